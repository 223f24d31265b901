//! The registry of live handles: a pointer the caller passes is used only
//! if this library handed it out and it was not freed since.

use std::collections::HashSet;
use std::sync::Mutex;

/// Addresses of the handles alive now.
static HANDLES: Mutex<Option<HashSet<usize>>> = Mutex::new(None);

pub(crate) fn register<T>(b: Box<T>) -> *mut T {
    let p = Box::into_raw(b);
    let mut h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    h.get_or_insert_with(HashSet::new).insert(p as usize);
    p
}

pub(crate) fn is_live<T>(p: *const T) -> bool {
    let h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    !p.is_null() && h.as_ref().is_some_and(|s| s.contains(&(p as usize)))
}

pub(crate) fn unregister<T>(p: *mut T) -> Option<Box<T>> {
    let mut h = HANDLES.lock().unwrap_or_else(|e| e.into_inner());
    let removed = h.as_mut().is_some_and(|s| s.remove(&(p as usize)));
    // SAFETY: registered pointers come from Box::into_raw and are removed
    // from the registry exactly once, here.
    removed.then(|| unsafe { Box::from_raw(p) })
}

//! # latentam-base
//!
//! What every layer of latentam shares: the error type, files written whole
//! or not at all, the one declaration of each configuration setting
//! ([`settings!`]), and the host-side data model the GPU layers mirror and
//! the CPU references read: the pinhole [`Camera`] and [`HostGaussians`].
//!
//! Nothing here touches a GPU or a log. Robot programs use these types
//! through the `latentam` crate, which re-exports what its API needs.
//!
//! ```
//! use latentam_base::{Camera, HostGaussians};
//!
//! let cam = Camera::at_origin(640, 480);
//! let map = HostGaussians::zeros(3);
//! assert_eq!((cam.width, map.len()?), (640, 3));
//! # Ok::<(), latentam_base::Error>(())
//! ```

#![warn(missing_docs)]

pub mod background;
mod camera;
mod error;
#[doc(hidden)]
pub mod faults;
pub mod files;
mod gaussians;
pub mod process;
#[doc(hidden)]
pub mod random;
pub mod settings;
pub mod text;

pub use camera::{Camera, GUARD_BAND};
pub use error::{Error, InputError, Rejection, Result, VkContext};
pub use gaussians::{HostGaussians, QUERY_DIM};

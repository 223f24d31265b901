//! Duplicate keys in JSON read from files.
//!
//! JSON allows an object to name a key twice and leaves the meaning open;
//! serde keeps the last one, Python's `json` too, other readers the first.
//! A safetensors header or a run report that names a tensor, its offsets
//! or a run id twice therefore reads differently in different tools, and a
//! file edited to carry a second `run_id` would pass a check the first one
//! fails. Files from other hands are refused instead.

use std::collections::HashSet;
use std::fmt;

use serde::de::{self, Deserialize, Deserializer, MapAccess, SeqAccess, Visitor};

/// Checks that no object in the JSON text `json`, at any depth, names a key
/// twice. The error says which key (escaped and cut for the terminal); a
/// text that is not JSON gives the parser's message.
pub fn check_json_keys(json: &str) -> Result<(), String> {
    serde_json::from_str::<UniqueKeys>(json)
        .map(|_| ())
        .map_err(|e| e.to_string())
}

/// Parses JSON text read from a file into a value, refusing any key named
/// twice in one object (see [`check_json_keys`]).
pub fn parse_json(json: &str) -> Result<serde_json::Value, String> {
    check_json_keys(json)?;
    serde_json::from_str(json).map_err(|e| e.to_string())
}

/// [`check_json_keys`] on the header of a safetensors file (8 bytes of
/// little-endian length, then the JSON). Bytes too short or not text pass:
/// the safetensors reader refuses those with its own message.
pub fn check_safetensors_keys(bytes: &[u8]) -> Result<(), String> {
    let Some(len) = bytes.get(..8) else {
        return Ok(());
    };
    let len = u64::from_le_bytes(len.try_into().expect("8 bytes"));
    let header = usize::try_from(len)
        .ok()
        .and_then(|n| bytes.get(8..8usize.checked_add(n)?))
        .and_then(|h| std::str::from_utf8(h).ok());
    match header {
        Some(h) => check_json_keys(h).map_err(|e| format!("header: {e}")),
        None => Ok(()),
    }
}

/// Any JSON value, read only to see that its objects' keys are unique.
struct UniqueKeys;

impl<'de> Deserialize<'de> for UniqueKeys {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        d.deserialize_any(UniqueKeysVisitor)
    }
}

struct UniqueKeysVisitor;

impl<'de> Visitor<'de> for UniqueKeysVisitor {
    type Value = UniqueKeys;

    fn expecting(&self, f: &mut fmt::Formatter) -> fmt::Result {
        f.write_str("a JSON value")
    }

    fn visit_bool<E>(self, _: bool) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }
    fn visit_i64<E>(self, _: i64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }
    fn visit_u64<E>(self, _: u64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }
    fn visit_f64<E>(self, _: f64) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }
    fn visit_str<E>(self, _: &str) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }
    fn visit_unit<E>(self) -> Result<UniqueKeys, E> {
        Ok(UniqueKeys)
    }

    fn visit_seq<A: SeqAccess<'de>>(self, mut seq: A) -> Result<UniqueKeys, A::Error> {
        while seq.next_element::<UniqueKeys>()?.is_some() {}
        Ok(UniqueKeys)
    }

    fn visit_map<A: MapAccess<'de>>(self, mut map: A) -> Result<UniqueKeys, A::Error> {
        let mut seen = HashSet::new();
        while let Some(key) = map.next_key::<String>()? {
            if !seen.insert(key.clone()) {
                return Err(de::Error::custom(format!(
                    "key \"{}\" appears twice in one object",
                    latentam_base::text::shown(&key)
                )));
            }
            map.next_value::<UniqueKeys>()?;
        }
        Ok(UniqueKeys)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_key_named_twice_at_any_depth_is_refused_and_named() {
        for (text, key) in [
            (r#"{"a": 1, "a": 2}"#, "a"),
            (r#"{"t": {"dtype": "F32", "dtype": "U8"}}"#, "dtype"),
            (r#"[{"x": [1, {"run_id": "a", "run_id": "b"}]}]"#, "run_id"),
        ] {
            let e = check_json_keys(text).unwrap_err();
            assert!(e.contains(&format!("\"{key}\" appears twice")), "{e}");
        }
    }

    #[test]
    fn unique_keys_and_the_same_key_in_different_objects_pass() {
        for text in [
            r#"{"a": 1, "b": {"a": 2}, "c": [{"a": 3}, {"a": 4}]}"#,
            r#"{"__metadata__": {"k": "v"}, "t": {"dtype": "F32", "shape": [2], "data_offsets": [0, 8]}}"#,
            "[]",
            "3",
        ] {
            check_json_keys(text).unwrap();
        }
    }

    #[test]
    fn a_key_with_control_characters_is_shown_escaped() {
        let e = check_json_keys("{\"\\u001b[2J\": 1, \"\\u001b[2J\": 2}").unwrap_err();
        assert!(!e.contains('\u{1b}'), "{e:?}");
    }

    #[test]
    fn safetensors_headers_are_checked_and_other_bytes_left_to_the_reader() {
        let file = |header: &str| {
            let mut b = (header.len() as u64).to_le_bytes().to_vec();
            b.extend_from_slice(header.as_bytes());
            b
        };
        let twice = r#"{"w": {"dtype": "F32", "shape": [0], "data_offsets": [0, 0]}, "w": {"dtype": "U8", "shape": [0], "data_offsets": [0, 0]}}"#;
        assert!(check_safetensors_keys(&file(twice))
            .unwrap_err()
            .contains("\"w\" appears twice"));
        check_safetensors_keys(&file(r#"{"w": {}}"#)).unwrap();
        check_safetensors_keys(b"short").unwrap();
        check_safetensors_keys(&u64::MAX.to_le_bytes()).unwrap();
    }
}

//! Names of semantic class ids from a log's metadata: the record
//! `latentam`, key `semantic_classes`, holding an id → name table as JSON
//! (`{"10": "wall", "93": "door"}`) or a looser form of it (single quotes,
//! bare ids, a list of `[id, "name"]` pairs). Evaluation names its classes
//! from the vocabulary first, then from this table.

use std::collections::BTreeMap;
use std::path::Path;

use super::log::McapLog;
use super::InputError;

/// Metadata record and key of the class table.
pub const CLASS_NAMES_METADATA: (&str, &str) = ("latentam", "semantic_classes");

/// The class table of the log at `path` (empty when it has none).
pub fn read_class_names(path: &Path) -> Result<BTreeMap<u16, String>, InputError> {
    let log = McapLog::open(path)?;
    let mut names = BTreeMap::new();
    for (record, values) in log.metadata()? {
        if record != CLASS_NAMES_METADATA.0 {
            continue;
        }
        if let Some(table) = values.get(CLASS_NAMES_METADATA.1) {
            names.extend(parse_class_names(table));
        }
    }
    Ok(names)
}

/// Every `id: "name"` (or `[id, "name"]`) pair of `text`, in the order
/// found; ids that do not fit a u16 are skipped.
pub fn parse_class_names(text: &str) -> BTreeMap<u16, String> {
    let chars: Vec<char> = text.chars().collect();
    let mut out = BTreeMap::new();
    let mut i = 0;
    while i < chars.len() {
        if !chars[i].is_ascii_digit() || (i > 0 && chars[i - 1].is_alphanumeric()) {
            i += 1;
            continue;
        }
        let start = i;
        while i < chars.len() && chars[i].is_ascii_digit() {
            i += 1;
        }
        let id: String = chars[start..i].iter().collect();
        // An optional closing quote of the id, then `:` or `,`, then a
        // quoted name.
        let mut j = i;
        if j < chars.len() && (chars[j] == '"' || chars[j] == '\'') {
            j += 1;
        }
        while j < chars.len() && chars[j].is_whitespace() {
            j += 1;
        }
        if j >= chars.len() || (chars[j] != ':' && chars[j] != ',') {
            continue;
        }
        j += 1;
        while j < chars.len() && chars[j].is_whitespace() {
            j += 1;
        }
        let Some(&quote) = chars.get(j).filter(|c| **c == '"' || **c == '\'') else {
            continue;
        };
        let name_start = j + 1;
        let Some(len) = chars[name_start..].iter().position(|&c| c == quote) else {
            break;
        };
        let name: String = chars[name_start..name_start + len].iter().collect();
        if let Ok(id) = id.parse::<u16>() {
            if !name.trim().is_empty() {
                out.insert(id, name.trim().to_string());
            }
        }
        i = name_start + len + 1;
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn json_and_looser_tables_parse() {
        let json = parse_class_names(r#"{"0": "undefined", "10": "wall", "93": "door"}"#);
        assert_eq!(json.len(), 3);
        assert_eq!(json[&10], "wall");
        let loose = parse_class_names("{0: 'floor', 12:'table lamp' , 7 : \"bed\"}");
        assert_eq!(loose[&12], "table lamp");
        assert_eq!(loose[&7], "bed");
        let pairs = parse_class_names(r#"[[3, "sofa"], [4, "rug"]]"#);
        assert_eq!(pairs[&3], "sofa");
        assert_eq!(pairs[&4], "rug");
        // Not a table: nothing, and no panic.
        assert!(parse_class_names("model v2 (2024), 768-d").is_empty());
        assert!(parse_class_names("{\"70000\": \"too big\", \"5\": \"ok\"").len() == 1);
        assert!(parse_class_names("{\"5\": \"unterminated").is_empty());
        assert!(parse_class_names("").is_empty());
    }
}

//! The node's settings as ROS 2 parameters, served by the standard
//! parameter services (`rcl_interfaces/srv/*`, what `ros2 param list`,
//! `get`, `set`, `describe` and `dump` call): the mapper's configuration,
//! read-only for the run (every key of `latentam config
//! --print-defaults`, sections as dotted names), and the node's own
//! publishing settings, which take effect at once when set.

use std::collections::BTreeMap;

use anyhow::{anyhow, Result};
use latentam::messages::cdr::{CdrError, CdrReader, CdrWriter};

/// `rcl_interfaces/msg/ParameterType`.
mod kind {
    pub const NOT_SET: u8 = 0;
    pub const BOOL: u8 = 1;
    pub const INTEGER: u8 = 2;
    pub const DOUBLE: u8 = 3;
    pub const STRING: u8 = 4;
    pub const BYTE_ARRAY: u8 = 5;
    pub const BOOL_ARRAY: u8 = 6;
    pub const INTEGER_ARRAY: u8 = 7;
    pub const DOUBLE_ARRAY: u8 = 8;
    pub const STRING_ARRAY: u8 = 9;
}

/// An `rcl_interfaces/msg/ParameterValue`.
#[derive(Clone, Debug, PartialEq)]
pub enum Value {
    NotSet,
    Bool(bool),
    Integer(i64),
    Double(f64),
    String(String),
    Bytes(Vec<u8>),
    Bools(Vec<bool>),
    Integers(Vec<i64>),
    Doubles(Vec<f64>),
    Strings(Vec<String>),
}

impl Value {
    pub fn kind(&self) -> u8 {
        match self {
            Value::NotSet => kind::NOT_SET,
            Value::Bool(_) => kind::BOOL,
            Value::Integer(_) => kind::INTEGER,
            Value::Double(_) => kind::DOUBLE,
            Value::String(_) => kind::STRING,
            Value::Bytes(_) => kind::BYTE_ARRAY,
            Value::Bools(_) => kind::BOOL_ARRAY,
            Value::Integers(_) => kind::INTEGER_ARRAY,
            Value::Doubles(_) => kind::DOUBLE_ARRAY,
            Value::Strings(_) => kind::STRING_ARRAY,
        }
    }

    /// Every field of the message, the one of its kind filled.
    pub fn encode(&self, w: &mut CdrWriter) {
        w.put(self.kind());
        w.bool(matches!(self, Value::Bool(true)));
        w.put(match self {
            Value::Integer(i) => *i,
            _ => 0i64,
        });
        w.put(match self {
            Value::Double(d) => *d,
            _ => 0f64,
        });
        w.string(match self {
            Value::String(s) => s,
            _ => "",
        });
        w.bytes(match self {
            Value::Bytes(b) => b,
            _ => &[],
        });
        let bools: Vec<u8> = match self {
            Value::Bools(b) => b.iter().map(|&v| v as u8).collect(),
            _ => Vec::new(),
        };
        w.bytes(&bools);
        w.seq::<i64>(match self {
            Value::Integers(v) => v,
            _ => &[],
        });
        w.seq::<f64>(match self {
            Value::Doubles(v) => v,
            _ => &[],
        });
        let strings: Vec<&str> = match self {
            Value::Strings(v) => v.iter().map(String::as_str).collect(),
            _ => Vec::new(),
        };
        w.strings(&strings);
    }

    pub fn decode(r: &mut CdrReader<'_>) -> Result<Value, CdrError> {
        let kind = r.read::<u8>("type")?;
        let b = r.bool("bool_value")?;
        let i = r.read::<i64>("integer_value")?;
        let d = r.read::<f64>("double_value")?;
        let s = r.string("string_value")?.to_string();
        let bytes = r.bytes("byte_array_value")?.to_vec();
        let bools: Vec<bool> = r
            .bytes("bool_array_value")?
            .iter()
            .map(|&v| v != 0)
            .collect();
        let ints = r.seq::<i64>("integer_array_value")?.to_vec();
        let doubles = r.seq::<f64>("double_array_value")?.to_vec();
        let strings: Vec<String> = r
            .strings("string_array_value")?
            .into_iter()
            .map(str::to_string)
            .collect();
        Ok(match kind {
            kind::BOOL => Value::Bool(b),
            kind::INTEGER => Value::Integer(i),
            kind::DOUBLE => Value::Double(d),
            kind::STRING => Value::String(s),
            kind::BYTE_ARRAY => Value::Bytes(bytes),
            kind::BOOL_ARRAY => Value::Bools(bools),
            kind::INTEGER_ARRAY => Value::Integers(ints),
            kind::DOUBLE_ARRAY => Value::Doubles(doubles),
            kind::STRING_ARRAY => Value::Strings(strings),
            _ => Value::NotSet,
        })
    }

    /// A TOML value as a parameter (tables are flattened by the caller;
    /// arrays of mixed kinds as strings).
    fn of_toml(v: &toml::Value) -> Value {
        match v {
            toml::Value::Boolean(b) => Value::Bool(*b),
            toml::Value::Integer(i) => Value::Integer(*i),
            toml::Value::Float(f) => Value::Double(*f),
            toml::Value::String(s) => Value::String(s.clone()),
            toml::Value::Array(items) => {
                if let Some(v) = items.iter().map(|x| x.as_integer()).collect() {
                    Value::Integers(v)
                } else if let Some(v) = items.iter().map(|x| x.as_float()).collect() {
                    Value::Doubles(v)
                } else if let Some(v) = items.iter().map(|x| x.as_bool()).collect() {
                    Value::Bools(v)
                } else {
                    Value::Strings(items.iter().map(|x| x.to_string()).collect())
                }
            }
            other => Value::String(other.to_string()),
        }
    }
}

/// The node's publishing settings, the parameters that may be set.
#[derive(Clone, Debug, PartialEq)]
pub struct Publishing {
    pub frame_id: String,
    pub map_every: f64,
    pub map_points: usize,
    pub words: Vec<String>,
    pub temperature: f32,
}

impl Publishing {
    fn values(&self) -> [(&'static str, Value, &'static str); 5] {
        [
            (
                "frame_id",
                Value::String(self.frame_id.clone()),
                "frame of the map, trajectory and relevance clouds (--frame-id)",
            ),
            (
                "map_every",
                Value::Double(self.map_every),
                "least seconds between two publications of the map (--map-every)",
            ),
            (
                "map_points",
                Value::Integer(self.map_points as i64),
                "most points in a published cloud (--map-points)",
            ),
            (
                "words",
                Value::Strings(self.words.clone()),
                "vocabulary words whose relevance rides on the map cloud (--words)",
            ),
            (
                "temperature",
                Value::Double(self.temperature as f64),
                "softmax temperature of relevance over several words (--temperature)",
            ),
        ]
    }

    /// Sets `name` to `value`, or says why not.
    fn set(&mut self, name: &str, value: &Value) -> std::result::Result<(), String> {
        match (name, value) {
            ("frame_id", Value::String(s)) if !s.trim().is_empty() => self.frame_id = s.clone(),
            ("frame_id", Value::String(_)) => return Err("frame_id must not be empty".into()),
            ("map_every", Value::Double(d)) if *d >= 0.0 && d.is_finite() => self.map_every = *d,
            ("map_every", Value::Double(_)) => {
                return Err("map_every must be a number of seconds, 0 or more".into())
            }
            ("map_points", Value::Integer(i)) if *i >= 1 => self.map_points = *i as usize,
            ("map_points", Value::Integer(_)) => return Err("map_points must be at least 1".into()),
            ("words", Value::Strings(w)) => self.words = w.clone(),
            // Positive and finite as the f32 it becomes.
            ("temperature", Value::Double(t)) if (*t as f32).is_finite() && *t as f32 > 0.0 => {
                self.temperature = *t as f32
            }
            ("temperature", Value::Double(_)) => {
                return Err("temperature must be positive and finite".into())
            }
            _ => {
                let want = self
                    .values()
                    .into_iter()
                    .find(|(n, ..)| *n == name)
                    .map(|(_, v, _)| v.kind());
                return Err(match want {
                    Some(k) => format!("{name} takes a value of type {}", kind_name(k)),
                    None => format!("no parameter {name}"),
                });
            }
        }
        Ok(())
    }
}

fn kind_name(k: u8) -> &'static str {
    [
        "not set",
        "bool",
        "integer",
        "double",
        "string",
        "byte array",
        "bool array",
        "integer array",
        "double array",
        "string array",
    ]
    .get(k as usize)
    .copied()
    .unwrap_or("unknown")
}

/// One parameter: its value, whether it may be set, what it is.
struct Entry {
    value: Value,
    read_only: bool,
    description: String,
}

/// The node's parameters.
pub struct Parameters {
    entries: BTreeMap<String, Entry>,
    pub publishing: Publishing,
}

impl Parameters {
    /// The mapper configuration `config_toml` (its effective TOML) and the
    /// publishing settings.
    pub fn new(config_toml: &str, publishing: Publishing) -> Result<Self> {
        let table: toml::Table = config_toml
            .parse()
            .map_err(|e| anyhow!("the mapper configuration as TOML: {e}"))?;
        let mut entries = BTreeMap::new();
        flatten("", &table, &mut entries);
        let mut p = Parameters {
            entries,
            publishing,
        };
        p.refresh();
        Ok(p)
    }

    fn refresh(&mut self) {
        for (name, value, description) in self.publishing.values() {
            self.entries.insert(
                name.to_string(),
                Entry {
                    value,
                    read_only: false,
                    description: description.to_string(),
                },
            );
        }
    }

    /// `get_parameters`: the values of `names` (not set for an unknown one).
    pub fn get(&self, names: &[&str]) -> Vec<Value> {
        names
            .iter()
            .map(|n| {
                self.entries
                    .get(*n)
                    .map_or(Value::NotSet, |e| e.value.clone())
            })
            .collect()
    }

    /// `list_parameters`: the names under `prefixes` (all when empty) at
    /// most `depth` dots below them (0: any depth), and the prefixes
    /// (sections) they are in.
    pub fn list(&self, prefixes: &[&str], depth: u64) -> (Vec<String>, Vec<String>) {
        let mut names = Vec::new();
        let mut sections = Vec::new();
        for name in self.entries.keys() {
            let under = |p: &&str| p.is_empty() || name.starts_with(&format!("{p}."));
            let base = if prefixes.is_empty() {
                Some("")
            } else {
                prefixes.iter().copied().find(|p| under(p))
            };
            let Some(base) = base else { continue };
            let rest = name[base.len()..].trim_start_matches('.');
            if depth != 0 && rest.matches('.').count() as u64 >= depth {
                continue;
            }
            names.push(name.clone());
            if let Some((section, _)) = name.rsplit_once('.') {
                if !sections.iter().any(|s| s == section) {
                    sections.push(section.to_string());
                }
            }
        }
        (names, sections)
    }

    /// `set_parameters`: each one set or refused with a reason; a
    /// refused one changes nothing.
    pub fn set(&mut self, name: &str, value: &Value) -> std::result::Result<(), String> {
        match self.entries.get(name) {
            None => return Err(format!("no parameter {name}")),
            Some(e) if e.read_only => {
                return Err(format!(
                    "{name} is read-only: the mapper's configuration is fixed for a run \
                     (set it with --config or --set when starting the node)"
                ))
            }
            Some(_) => {}
        }
        self.publishing.set(name, value)?;
        self.refresh();
        Ok(())
    }

    /// `set_parameters_atomically`: all or none.
    pub fn set_all(&mut self, values: &[(String, Value)]) -> std::result::Result<(), String> {
        let before = self.publishing.clone();
        for (name, value) in values {
            if let Err(e) = self.set(name, value) {
                self.publishing = before;
                self.refresh();
                return Err(e);
            }
        }
        Ok(())
    }

    /// `describe_parameters`: an `rcl_interfaces/msg/ParameterDescriptor`
    /// per name (an unknown one: its name and type not set).
    pub fn describe(&self, name: &str, w: &mut CdrWriter) {
        let entry = self.entries.get(name);
        w.string(name);
        w.put(entry.map_or(kind::NOT_SET, |e| e.value.kind()));
        w.string(entry.map_or("", |e| e.description.as_str()));
        w.string(""); // additional_constraints
        w.bool(entry.is_none_or(|e| e.read_only));
        w.bool(false); // dynamic_typing
        w.put(0u32); // no floating_point_range
        w.put(0u32); // no integer_range
    }

    /// `get_parameter_types`.
    pub fn kinds(&self, names: &[&str]) -> Vec<u8> {
        self.get(names).iter().map(Value::kind).collect()
    }
}

/// Every key of `table` as a dotted name.
fn flatten(prefix: &str, table: &toml::Table, out: &mut BTreeMap<String, Entry>) {
    for (key, value) in table {
        let name = if prefix.is_empty() {
            key.clone()
        } else {
            format!("{prefix}.{key}")
        };
        match value {
            toml::Value::Table(t) => flatten(&name, t, out),
            v => {
                out.insert(
                    name,
                    Entry {
                        value: Value::of_toml(v),
                        read_only: true,
                        description: "the mapper's configuration (latentam config \
                                      --print-defaults documents every key); read-only"
                            .into(),
                    },
                );
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use latentam::messages::cdr::Endian;

    fn publishing() -> Publishing {
        Publishing {
            frame_id: "map".into(),
            map_every: 1.0,
            map_points: 100,
            words: vec!["chair".into()],
            temperature: 0.1,
        }
    }

    fn params() -> Parameters {
        let toml = "voxel_size = 0.01\nreplay = 5\n[seeding]\nstride = 4\nmode = \"grid\"\n";
        Parameters::new(toml, publishing()).unwrap()
    }

    #[test]
    fn values_round_trip_through_cdr() {
        for v in [
            Value::NotSet,
            Value::Bool(true),
            Value::Integer(-7),
            Value::Double(0.25),
            Value::String("map".into()),
            Value::Bytes(vec![1, 2]),
            Value::Bools(vec![true, false]),
            Value::Integers(vec![1, -2, 3]),
            Value::Doubles(vec![0.5]),
            Value::Strings(vec!["a".into(), "bc".into()]),
        ] {
            let mut w = CdrWriter::new(Endian::Little);
            v.encode(&mut w);
            let bytes = w.finish();
            let got = Value::decode(&mut CdrReader::new(&bytes).unwrap()).unwrap();
            assert_eq!(got, v);
        }
    }

    /// The fixed part of a ParameterValue, field by field: type, bool,
    /// then the int64 and float64 at their 8-byte alignment.
    #[test]
    fn value_layout_matches_cdr() {
        let mut w = CdrWriter::new(Endian::Little);
        Value::Integer(5).encode(&mut w);
        let b = w.finish();
        assert_eq!(&b[4..6], &[kind::INTEGER, 0]);
        assert_eq!(&b[4 + 8..4 + 16], &5i64.to_le_bytes());
        assert_eq!(&b[4 + 16..4 + 24], &0f64.to_le_bytes());
    }

    #[test]
    fn configuration_is_listed_read_only_and_publishing_settable() {
        let mut p = params();
        let (names, sections) = p.list(&[], 0);
        for n in ["voxel_size", "seeding.stride", "map_every", "words"] {
            assert!(names.iter().any(|x| x == n), "{names:?}");
        }
        assert_eq!(sections, ["seeding"]);
        let (top, _) = p.list(&[], 1);
        assert!(!top.iter().any(|x| x.contains('.')), "{top:?}");
        let (seeding, _) = p.list(&["seeding"], 0);
        assert_eq!(seeding, ["seeding.mode", "seeding.stride"]);
        assert_eq!(
            p.get(&["voxel_size", "seeding.stride", "nope"]),
            [Value::Double(0.01), Value::Integer(4), Value::NotSet]
        );
        assert!(p
            .set("voxel_size", &Value::Double(0.02))
            .unwrap_err()
            .contains("read-only"));
        assert!(p
            .set("map_points", &Value::String("x".into()))
            .unwrap_err()
            .contains("integer"));
        assert!(p.set("map_every", &Value::Double(-1.0)).is_err());
        p.set("map_every", &Value::Double(0.5)).unwrap();
        assert_eq!(p.publishing.map_every, 0.5);
        assert_eq!(p.get(&["map_every"]), [Value::Double(0.5)]);
        // All or none.
        let err = p.set_all(&[
            ("map_points".into(), Value::Integer(7)),
            ("temperature".into(), Value::Double(0.0)),
        ]);
        assert!(err.is_err());
        assert_eq!(p.publishing.map_points, 100);
        assert_eq!(p.get(&["map_points"]), [Value::Integer(100)]);
        assert_eq!(
            p.kinds(&["frame_id", "words", "x"]),
            [kind::STRING, kind::STRING_ARRAY, 0]
        );
    }
}

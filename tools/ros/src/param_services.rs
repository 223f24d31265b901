//! The standard parameter services of a ROS 2 node
//! (`rcl_interfaces/srv/GetParameters`, `GetParameterTypes`,
//! `SetParameters`, `SetParametersAtomically`, `ListParameters`,
//! `DescribeParameters`) on the node's [`Parameters`].

use anyhow::Result;
use latentam::frames::Vocabulary;
use latentam::messages::cdr::{CdrError, CdrReader, CdrWriter};

use crate::dds::Dds;
use crate::params::{Parameters, Value};
use crate::services::{Mapping, Service};

/// The six services, under the node's name (`/latentam/get_parameters`, ...).
pub struct ParameterServices {
    get: Service,
    get_types: Service,
    set: Service,
    set_atomically: Service,
    list: Service,
    describe: Service,
}

impl ParameterServices {
    pub fn new(dds: &Dds, node: &str, mapping: Mapping) -> Result<Self> {
        let service = |name: &str, ty: &str| {
            Service::new(
                dds,
                &format!("{}/{name}", node.trim_end_matches('/')),
                &format!("rcl_interfaces/srv/{ty}"),
                mapping,
            )
        };
        Ok(ParameterServices {
            get: service("get_parameters", "GetParameters")?,
            get_types: service("get_parameter_types", "GetParameterTypes")?,
            set: service("set_parameters", "SetParameters")?,
            set_atomically: service("set_parameters_atomically", "SetParametersAtomically")?,
            list: service("list_parameters", "ListParameters")?,
            describe: service("describe_parameters", "DescribeParameters")?,
        })
    }

    /// Answers every request waiting. `vocabulary` (once it arrived)
    /// checks the words set.
    pub fn serve(&mut self, params: &mut Parameters, vocabulary: Option<&Vocabulary>, node: &str) {
        while let Some(request) = self.get.take() {
            match decode(&request.message, |r| r.strings("names").map(owned)) {
                Ok(names) => {
                    let values = params.get(&borrowed(&names));
                    self.get.reply(request, |w| {
                        w.put(values.len() as u32);
                        values.iter().for_each(|v| v.encode(w));
                    });
                }
                Err(e) => log::warn!("{node}/get_parameters: {e}"),
            }
        }
        while let Some(request) = self.get_types.take() {
            match decode(&request.message, |r| r.strings("names").map(owned)) {
                Ok(names) => {
                    let kinds = params.kinds(&borrowed(&names));
                    self.get_types.reply(request, |w| w.bytes(&kinds));
                }
                Err(e) => log::warn!("{node}/get_parameter_types: {e}"),
            }
        }
        while let Some(request) = self.describe.take() {
            match decode(&request.message, |r| r.strings("names").map(owned)) {
                Ok(names) => self.describe.reply(request, |w| {
                    w.put(names.len() as u32);
                    names.iter().for_each(|n| params.describe(n, w));
                }),
                Err(e) => log::warn!("{node}/describe_parameters: {e}"),
            }
        }
        while let Some(request) = self.list.take() {
            let read = decode(&request.message, |r| {
                let prefixes = r.strings("prefixes").map(owned)?;
                Ok((prefixes, r.read::<u64>("depth")?))
            });
            match read {
                Ok((prefixes, depth)) => {
                    let (names, sections) = params.list(&borrowed(&prefixes), depth);
                    self.list.reply(request, |w| {
                        w.strings(&borrowed(&names));
                        w.strings(&borrowed(&sections));
                    });
                }
                Err(e) => log::warn!("{node}/list_parameters: {e}"),
            }
        }
        while let Some(request) = self.set.take() {
            match decode(&request.message, parameters) {
                Ok(list) => {
                    let results: Vec<Result<(), String>> = list
                        .iter()
                        .map(|(n, v)| {
                            checked_words(n, v, vocabulary).and_then(|_| params.set(n, v))
                        })
                        .collect();
                    log_sets(node, &list, &results);
                    self.set.reply(request, |w| {
                        w.put(results.len() as u32);
                        results.iter().for_each(|r| set_result(w, r));
                    });
                }
                Err(e) => log::warn!("{node}/set_parameters: {e}"),
            }
        }
        while let Some(request) = self.set_atomically.take() {
            match decode(&request.message, parameters) {
                Ok(list) => {
                    let result = list
                        .iter()
                        .try_for_each(|(n, v)| checked_words(n, v, vocabulary))
                        .and_then(|_| params.set_all(&list));
                    log_sets(node, &list, std::slice::from_ref(&result));
                    self.set_atomically
                        .reply(request, |w| set_result(w, &result));
                }
                Err(e) => log::warn!("{node}/set_parameters_atomically: {e}"),
            }
        }
    }
}

fn decode<T>(
    message: &[u8],
    read: impl FnOnce(&mut CdrReader<'_>) -> Result<T, CdrError>,
) -> Result<T, CdrError> {
    read(&mut CdrReader::new(message)?)
}

fn owned(v: Vec<&str>) -> Vec<String> {
    v.into_iter().map(str::to_string).collect()
}

fn borrowed(v: &[String]) -> Vec<&str> {
    v.iter().map(String::as_str).collect()
}

/// `rcl_interfaces/msg/Parameter[]`.
fn parameters(r: &mut CdrReader<'_>) -> Result<Vec<(String, Value)>, CdrError> {
    // A parameter is at least a name's length and a value's fixed part.
    let count = r.sequence_len("parameters", 4 + 24)?;
    (0..count)
        .map(|_| Ok((r.string("name")?.to_string(), Value::decode(r)?)))
        .collect()
}

/// `rcl_interfaces/msg/SetParametersResult`.
fn set_result(w: &mut CdrWriter, r: &Result<(), String>) {
    w.bool(r.is_ok());
    w.string(r.as_ref().err().map_or("", String::as_str));
}

/// Words must be the vocabulary's, which must have arrived.
fn checked_words(name: &str, value: &Value, vocabulary: Option<&Vocabulary>) -> Result<(), String> {
    let Value::Strings(words) = value else {
        return Ok(());
    };
    if name != "words" {
        return Ok(());
    }
    let Some(v) = vocabulary else {
        return Err("words: the vocabulary topic has delivered no vocabulary yet".into());
    };
    match words.iter().find(|w| !v.names.contains(w)) {
        Some(w) => Err(format!(
            "words: `{w}` is not in the vocabulary; it has: {}",
            v.names.join(", ")
        )),
        None => Ok(()),
    }
}

fn log_sets(node: &str, list: &[(String, Value)], results: &[Result<(), String>]) {
    for ((name, value), result) in list.iter().zip(results.iter().cycle()) {
        match result {
            Ok(()) => log::info!("{node}: parameter {name} set to {value:?}"),
            Err(why) => log::warn!("{node}: parameter {name} not set: {why}"),
        }
    }
}

//! ROS 2 services over DDS, as rmw implementations carry them: requests
//! on `rq/NAMERequest` (type `pkg::srv::dds_::Srv_Request_`), replies on
//! `rr/NAMEReply` (`pkg::srv::dds_::Srv_Response_`), each reply tied to
//! its request. How it is tied depends on the rmw implementation, and
//! ROS 2 does not mix them on one service:
//!
//! - Cyclone DDS (`rmw_cyclonedds_cpp`) puts a 16-byte header (the
//!   client's id and the request's sequence number) before the fields of
//!   the request, and expects it back before the fields of the reply;
//! - Fast DDS (`rmw_fastrtps_cpp`, ROS 2's default) and Connext keep the
//!   fields alone and tie the reply with the RTPS "related sample
//!   identity" of the request.
//!
//! The node follows `RMW_IMPLEMENTATION`, as the ROS 2 nodes beside it do.

use latentam::messages::cdr::{CdrWriter, Endian};
use rustdds::rpc::SampleIdentity;
use rustdds::WriteOptionsBuilder;

use crate::dds::{Dds, Profile, RawMessage, RawReader, RawWriter};

/// How replies are tied to requests.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Mapping {
    /// A 16-byte header in the payload (`rmw_cyclonedds_cpp`).
    Cyclone,
    /// The request's sample identity in the reply's inline QoS
    /// (`rmw_fastrtps_cpp`, `rmw_connextdds`).
    SampleIdentity,
}

impl Mapping {
    /// The mapping of the rmw implementation `RMW_IMPLEMENTATION` names
    /// (ROS 2's default, Fast DDS, when it names none).
    pub fn of(rmw_implementation: Option<&str>) -> Self {
        match rmw_implementation {
            Some(rmw) if rmw.contains("cyclonedds") => Mapping::Cyclone,
            _ => Mapping::SampleIdentity,
        }
    }
}

/// The bytes of Cyclone's request header.
const CYCLONE_HEADER: usize = 16;

/// One service of the node: its request reader and reply writer.
pub struct Service {
    requests: RawReader,
    replies: RawWriter,
    mapping: Mapping,
    name: String,
}

/// A request taken: its fields as a standalone message (encapsulation
/// header and fields, what `RosMessage::decode` reads), and what ties the
/// reply to it.
pub struct Request {
    pub message: Vec<u8>,
    tie: Tie,
}

enum Tie {
    Header([u8; CYCLONE_HEADER]),
    Identity(SampleIdentity),
}

impl Service {
    /// The service `name` (a ROS name, `/latentam/query`) of type
    /// `ros_type` (`latentam_msgs/srv/Query`).
    pub fn new(dds: &Dds, name: &str, ros_type: &str, mapping: Mapping) -> anyhow::Result<Self> {
        let base = name.trim_start_matches('/');
        let (scope, srv) = ros_type
            .rsplit_once('/')
            .ok_or_else(|| anyhow::anyhow!("{ros_type} is not a service type"))?;
        let scope = scope.replace('/', "::");
        let requests = dds.raw_reader(
            &format!("rq/{base}Request"),
            &format!("{scope}::dds_::{srv}_Request_"),
            Profile::Default,
        )?;
        let replies = dds.raw_writer(
            &format!("rr/{base}Reply"),
            &format!("{scope}::dds_::{srv}_Response_"),
            Profile::Default,
        )?;
        Ok(Service {
            requests,
            replies,
            mapping,
            name: name.to_string(),
        })
    }

    /// The next request, if one came; a request too short for its header
    /// is logged and dropped.
    pub fn take(&mut self) -> Option<Request> {
        loop {
            let sample = match self.requests.take_next_sample() {
                Ok(Some(s)) => s,
                _ => return None,
            };
            let identity = sample.sample_info().sample_identity();
            let bytes = sample.into_value().0;
            match split(self.mapping, bytes, identity) {
                Some(r) => return Some(r),
                None => log::warn!("a request to {} too short for its header", self.name),
            }
        }
    }

    /// Replies to `request` with the fields `write` writes.
    pub fn reply(&self, request: Request, write: impl FnOnce(&mut CdrWriter)) {
        let mut w = CdrWriter::new(Endian::Little);
        let written = match request.tie {
            Tie::Header(header) => {
                w.array(&header);
                write(&mut w);
                self.replies.write(RawMessage(w.finish()), None).map(|_| ())
            }
            Tie::Identity(identity) => {
                write(&mut w);
                let options = WriteOptionsBuilder::new()
                    .related_sample_identity(identity)
                    .build();
                self.replies
                    .write_with_options(RawMessage(w.finish()), options)
                    .map(|_| ())
            }
        };
        if let Err(e) = written {
            log::warn!("replying on {}: {e:?}", self.name);
        }
    }
}

/// A request's message and tie from its payload (`bytes`: encapsulation
/// header, then the fields, after Cyclone's header where it has one).
fn split(mapping: Mapping, bytes: Vec<u8>, identity: SampleIdentity) -> Option<Request> {
    match mapping {
        Mapping::SampleIdentity => Some(Request {
            message: bytes,
            tie: Tie::Identity(identity),
        }),
        Mapping::Cyclone => {
            let header: [u8; CYCLONE_HEADER] = bytes.get(4..4 + CYCLONE_HEADER)?.try_into().ok()?;
            // The header is 16 bytes, a multiple of every CDR alignment:
            // the fields after it are aligned as in a message of their own.
            let mut message = bytes[..4].to_vec();
            message.extend_from_slice(&bytes[4 + CYCLONE_HEADER..]);
            Some(Request {
                message,
                tie: Tie::Header(header),
            })
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_rmw_implementation_chooses_the_mapping() {
        assert_eq!(Mapping::of(Some("rmw_cyclonedds_cpp")), Mapping::Cyclone);
        assert_eq!(
            Mapping::of(Some("rmw_fastrtps_cpp")),
            Mapping::SampleIdentity
        );
        assert_eq!(Mapping::of(None), Mapping::SampleIdentity);
    }

    #[test]
    fn cyclone_requests_lose_their_header_and_keep_their_fields() {
        let identity = SampleIdentity {
            writer_guid: rustdds::GUID::GUID_UNKNOWN,
            sequence_number: rustdds::SequenceNumber::from(1),
        };
        let mut bytes = vec![0, 1, 0, 0];
        bytes.extend(1..=16u8);
        bytes.extend([7, 0, 0, 0]);
        let r = split(Mapping::Cyclone, bytes.clone(), identity).unwrap();
        assert_eq!(r.message, [0, 1, 0, 0, 7, 0, 0, 0]);
        match r.tie {
            Tie::Header(h) => assert_eq!(h.to_vec(), (1..=16u8).collect::<Vec<_>>()),
            Tie::Identity(_) => panic!("the header is the tie"),
        }
        assert!(split(Mapping::Cyclone, bytes[..10].to_vec(), identity).is_none());
        let r = split(Mapping::SampleIdentity, bytes.clone(), identity).unwrap();
        assert_eq!(r.message, bytes);
    }
}

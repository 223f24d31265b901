//! DDS as ROS 2 uses it: topic and type names, QoS profiles, and readers
//! and writers of raw CDR payloads (the messages themselves are decoded
//! and encoded by `latentam::messages`, exactly as when they come from a
//! bag).

use std::sync::Mutex;
use std::time::Duration;

use bytes::Bytes;
use rustdds::no_key::{DataReader, DataWriter};
use rustdds::policy::{Durability, History, Reliability};
use rustdds::{
    DomainParticipant, QosPolicies, QosPolicyBuilder, RTPSEntity, RepresentationIdentifier,
    TopicKind,
};

use crate::graph::{self, ParticipantEntities};

/// A ROS 2 topic name (`/camera/color/image_raw`) as DDS names it
/// (`rt/camera/color/image_raw`).
pub fn dds_topic(ros: &str) -> String {
    format!("rt/{}", ros.trim_start_matches('/'))
}

/// The ROS 2 topic name of a DDS topic, if it is one (`rt/...`).
pub fn ros_topic(dds: &str) -> Option<String> {
    dds.strip_prefix("rt/").map(|t| format!("/{t}"))
}

/// A ROS 2 type (`sensor_msgs/msg/Image`) as DDS names it
/// (`sensor_msgs::msg::dds_::Image_`).
pub fn dds_type(ros: &str) -> String {
    let mut parts: Vec<&str> = ros.split('/').collect();
    let name = parts.pop().unwrap_or_default();
    format!("{}::dds_::{name}_", parts.join("::"))
}

/// The ROS 2 type of a DDS type name, if it is one.
pub fn ros_type(dds: &str) -> Option<String> {
    let (scope, name) = dds.rsplit_once("::dds_::")?;
    let name = name.strip_suffix('_')?;
    Some(format!("{}/{name}", scope.replace("::", "/")))
}

/// How a topic is read or written.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Profile {
    /// Camera streams: best effort, keep the last few (ROS 2's
    /// sensor-data profile); a reliable publisher matches it too.
    SensorData,
    /// Reliable, volatile, keep the last 10 (ROS 2's default).
    Default,
    /// Reliable and transient-local: a late subscriber still gets the
    /// last message (`/tf_static`, the vocabulary, the map).
    Latched,
}

impl Profile {
    pub fn qos(self) -> QosPolicies {
        let b = QosPolicyBuilder::new();
        let b = match self {
            Profile::SensorData => b
                .reliability(Reliability::BestEffort)
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 5 }),
            Profile::Default => b
                .reliability(Reliability::Reliable {
                    max_blocking_time: rustdds::Duration::from_millis(100),
                })
                .durability(Durability::Volatile)
                .history(History::KeepLast { depth: 10 }),
            Profile::Latched => b
                .reliability(Reliability::Reliable {
                    max_blocking_time: rustdds::Duration::from_millis(100),
                })
                .durability(Durability::TransientLocal)
                .history(History::KeepLast { depth: 1 }),
        };
        b.build()
    }
}

/// A serialized message as it came: its CDR payload with the 4-byte
/// encapsulation header in front, as bags store it.
#[derive(Debug)]
pub struct RawMessage(pub Vec<u8>);

/// Reads and writes [`RawMessage`]s.
pub struct RawAdapter;

impl rustdds::no_key::DeserializerAdapter<RawMessage> for RawAdapter {
    type Error = std::convert::Infallible;
    type Decoded = RawMessage;

    fn supported_encodings() -> &'static [RepresentationIdentifier] {
        &[
            RepresentationIdentifier::CDR_LE,
            RepresentationIdentifier::CDR_BE,
        ]
    }

    fn transform_decoded(decoded: RawMessage) -> RawMessage {
        decoded
    }
}

/// Keeps the payload and puts the encapsulation header back in front.
#[derive(Clone, Copy)]
pub struct RawDecoder;

impl<'de> rustdds::no_key::Decode<'de, RawMessage> for RawDecoder {
    type Error = std::convert::Infallible;

    fn decode_bytes(
        self,
        input_bytes: &'de [u8],
        encoding: RepresentationIdentifier,
    ) -> Result<RawMessage, Self::Error> {
        let mut v = Vec::with_capacity(input_bytes.len() + 4);
        v.extend_from_slice(&encoding.to_bytes());
        v.extend_from_slice(&[0, 0]);
        v.extend_from_slice(input_bytes);
        Ok(RawMessage(v))
    }
}

impl rustdds::no_key::DefaultDecoder<RawMessage> for RawAdapter {
    type Decoder = RawDecoder;
    const DECODER: Self::Decoder = RawDecoder;
}

impl rustdds::no_key::SerializerAdapter<RawMessage> for RawAdapter {
    type Error = std::convert::Infallible;

    fn output_encoding() -> RepresentationIdentifier {
        RepresentationIdentifier::CDR_LE
    }

    /// `latentam::messages` encodes little-endian CDR with its header;
    /// DDS adds its own.
    fn to_bytes(value: &RawMessage) -> Result<Bytes, Self::Error> {
        Ok(Bytes::copy_from_slice(value.0.get(4..).unwrap_or_default()))
    }
}

pub type RawReader = DataReader<RawMessage, RawAdapter>;
pub type RawWriter = DataWriter<RawMessage, RawAdapter>;

/// The DDS side of the node: one participant, one publisher and one
/// subscriber, and the node's entry in the ROS 2 graph.
pub struct Dds {
    pub participant: DomainParticipant,
    publisher: rustdds::Publisher,
    subscriber: rustdds::Subscriber,
    /// The GUIDs of the node's readers and writers, for the graph.
    endpoints: Mutex<Endpoints>,
    /// The writer of `ros_discovery_info`.
    discovery: RawWriter,
}

#[derive(Default)]
struct Endpoints {
    readers: Vec<[u8; 16]>,
    writers: Vec<[u8; 16]>,
}

impl Dds {
    /// Joins DDS domain `domain` (ROS 2's `ROS_DOMAIN_ID`).
    pub fn join(domain: u16) -> anyhow::Result<Self> {
        let participant = DomainParticipant::new(domain)
            .map_err(|e| anyhow::anyhow!("joining DDS domain {domain}: {e:?}"))?;
        let qos = QosPolicyBuilder::new().build();
        let publisher = participant
            .create_publisher(&qos)
            .map_err(|e| anyhow::anyhow!("a DDS publisher: {e:?}"))?;
        let subscriber = participant
            .create_subscriber(&qos)
            .map_err(|e| anyhow::anyhow!("a DDS subscriber: {e:?}"))?;
        // As rmw implementations publish it: reliable, transient-local,
        // the last sample kept for participants that join later.
        let latched = Profile::Latched.qos();
        let topic = participant
            .create_topic(
                graph::DISCOVERY_TOPIC.to_string(),
                graph::DISCOVERY_TYPE.to_string(),
                &latched,
                TopicKind::NoKey,
            )
            .map_err(|e| anyhow::anyhow!("the topic {}: {e:?}", graph::DISCOVERY_TOPIC))?;
        let discovery = publisher
            .create_datawriter_no_key::<RawMessage, RawAdapter>(&topic, Some(latched))
            .map_err(|e| anyhow::anyhow!("publishing {}: {e:?}", graph::DISCOVERY_TOPIC))?;
        Ok(Dds {
            participant,
            publisher,
            subscriber,
            endpoints: Mutex::new(Endpoints::default()),
            discovery,
        })
    }

    /// Publishes the node `name` in `namespace` with every reader and
    /// writer made so far on `ros_discovery_info` (again after each new
    /// one, as rmw implementations do).
    pub fn announce(&self, namespace: &str, name: &str) -> anyhow::Result<()> {
        let endpoints = self.endpoints.lock().unwrap_or_else(|e| e.into_inner());
        let message = ParticipantEntities {
            participant: self.participant.guid().to_bytes(),
            namespace,
            name,
            readers: &endpoints.readers,
            writers: &endpoints.writers,
            gid_bytes: graph::gid_bytes(std::env::var("ROS_DISTRO").ok().as_deref()),
        }
        .encode();
        self.discovery
            .write(RawMessage(message), None)
            .map_err(|e| anyhow::anyhow!("publishing {}: {e:?}", graph::DISCOVERY_TOPIC))
    }

    /// A reader of `ros_topic`, of type `ros_type`.
    pub fn reader(
        &self,
        ros_topic: &str,
        ros_type: &str,
        profile: Profile,
    ) -> anyhow::Result<RawReader> {
        self.raw_reader(&dds_topic(ros_topic), &dds_type(ros_type), profile)
            .map_err(|e| anyhow::anyhow!("reading {ros_topic}: {e:#}"))
    }

    /// A writer of `ros_topic`, of type `ros_type`.
    pub fn writer(
        &self,
        ros_topic: &str,
        ros_type: &str,
        profile: Profile,
    ) -> anyhow::Result<RawWriter> {
        self.raw_writer(&dds_topic(ros_topic), &dds_type(ros_type), profile)
            .map_err(|e| anyhow::anyhow!("publishing {ros_topic}: {e:#}"))
    }

    fn topic(
        &self,
        dds_topic: &str,
        dds_type: &str,
        profile: Profile,
    ) -> anyhow::Result<rustdds::Topic> {
        self.participant
            .create_topic(
                dds_topic.to_string(),
                dds_type.to_string(),
                &profile.qos(),
                TopicKind::NoKey,
            )
            .map_err(|e| anyhow::anyhow!("the DDS topic {dds_topic} ({dds_type}): {e:?}"))
    }

    /// A reader of the DDS topic `dds_topic` (named as DDS names it, e.g. a
    /// service's `rq/...Request`), of DDS type `dds_type`.
    pub fn raw_reader(
        &self,
        dds_topic: &str,
        dds_type: &str,
        profile: Profile,
    ) -> anyhow::Result<RawReader> {
        let topic = self.topic(dds_topic, dds_type, profile)?;
        let reader = self
            .subscriber
            .create_datareader_no_key::<RawMessage, RawAdapter>(&topic, Some(profile.qos()))
            .map_err(|e| anyhow::anyhow!("a reader of {dds_topic}: {e:?}"))?;
        self.endpoints
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .readers
            .push(reader.guid().to_bytes());
        Ok(reader)
    }

    /// A writer of the DDS topic `dds_topic`, of DDS type `dds_type`.
    pub fn raw_writer(
        &self,
        dds_topic: &str,
        dds_type: &str,
        profile: Profile,
    ) -> anyhow::Result<RawWriter> {
        let topic = self.topic(dds_topic, dds_type, profile)?;
        let writer = self
            .publisher
            .create_datawriter_no_key::<RawMessage, RawAdapter>(&topic, Some(profile.qos()))
            .map_err(|e| anyhow::anyhow!("a writer of {dds_topic}: {e:?}"))?;
        self.endpoints
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .writers
            .push(writer.guid().to_bytes());
        Ok(writer)
    }

    /// The ROS 2 topics some participant publishes now, with their types.
    pub fn published_topics(&self) -> Vec<(String, String)> {
        let mut seen: Vec<(String, String)> = self
            .participant
            .discovered_writers()
            .into_iter()
            .filter_map(|w| {
                let d = &w.publication_topic_data;
                Some((ros_topic(&d.topic_name)?, ros_type(&d.type_name)?))
            })
            .collect();
        seen.sort();
        seen.dedup();
        seen
    }
}

/// How long discovery is given before the topics are planned.
pub const DISCOVERY: Duration = Duration::from_secs(3);

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn names_map_both_ways() {
        assert_eq!(
            dds_topic("/camera/color/image_raw"),
            "rt/camera/color/image_raw"
        );
        assert_eq!(ros_topic("rt/tf_static").as_deref(), Some("/tf_static"));
        assert_eq!(ros_topic("DCPSParticipant"), None);
        assert_eq!(
            dds_type("sensor_msgs/msg/Image"),
            "sensor_msgs::msg::dds_::Image_"
        );
        assert_eq!(
            ros_type("latentam_msgs::msg::dds_::TextEmbeddings_").as_deref(),
            Some("latentam_msgs/msg/TextEmbeddings")
        );
        assert_eq!(ros_type("ShapeType"), None);
    }

    #[test]
    fn raw_messages_keep_the_encapsulation_header() {
        use rustdds::no_key::{Decode, SerializerAdapter};
        let payload = [1u8, 2, 3, 4, 5];
        let m = RawDecoder
            .decode_bytes(&payload, RepresentationIdentifier::CDR_LE)
            .unwrap();
        assert_eq!(m.0, [0, 1, 0, 0, 1, 2, 3, 4, 5]);
        assert_eq!(&RawAdapter::to_bytes(&m).unwrap()[..], &payload);
    }
}

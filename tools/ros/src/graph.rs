//! The node in the ROS 2 graph: what rmw implementations publish on
//! `ros_discovery_info` (`rmw_dds_common/msg/ParticipantEntitiesInfo`), so
//! that `ros2 node list` and `ros2 node info` show the node with its
//! topics. DDS discovery alone makes the topics visible, not the node.

use latentam::messages::cdr::{CdrWriter, Endian};

/// The DDS topic rmw implementations share (no `rt/` prefix: it is not a
/// ROS topic).
pub const DISCOVERY_TOPIC: &str = "ros_discovery_info";
/// Its DDS type.
pub const DISCOVERY_TYPE: &str = "rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_";

/// Bytes of an `rmw_dds_common/msg/Gid`: 24 up to Humble, 16 from Iron
/// on (the size of a DDS GUID). Read from `ROS_DISTRO`, which a sourced
/// ROS 2 installation sets; without it, the current layout.
pub fn gid_bytes(ros_distro: Option<&str>) -> usize {
    match ros_distro {
        Some("foxy" | "galactic" | "humble") => 24,
        _ => 16,
    }
}

/// A node's name and namespace from the namespace of its topics:
/// `/latentam` is the node `latentam` in `/`, `/robot1/latentam` the node
/// `latentam` in `/robot1` (its topics are its private names, `~/map`).
pub fn node_of(topic_namespace: &str) -> (String, String) {
    let trimmed = topic_namespace.trim_end_matches('/');
    match trimmed.rsplit_once('/') {
        Some(("", name)) => ("/".into(), name.into()),
        Some((ns, name)) => (ns.into(), name.into()),
        None => ("/".into(), trimmed.into()),
    }
}

/// What one participant holding one node publishes: the participant's
/// GUID, then the node with the GUIDs of its readers and writers, each as
/// a Gid of `gid_bytes` (the 16-byte GUID, zero-padded).
pub struct ParticipantEntities<'a> {
    pub participant: [u8; 16],
    pub namespace: &'a str,
    pub name: &'a str,
    pub readers: &'a [[u8; 16]],
    pub writers: &'a [[u8; 16]],
    pub gid_bytes: usize,
}

impl ParticipantEntities<'_> {
    /// The CDR message, encapsulation header included.
    pub fn encode(&self) -> Vec<u8> {
        let gid = |w: &mut CdrWriter, guid: &[u8; 16]| {
            let mut bytes = vec![0u8; self.gid_bytes];
            bytes[..16].copy_from_slice(guid);
            w.array(&bytes);
        };
        let mut w = CdrWriter::new(Endian::Little);
        gid(&mut w, &self.participant);
        w.put(1u32); // one node
        w.string(self.namespace);
        w.string(self.name);
        for list in [self.readers, self.writers] {
            w.put(list.len() as u32);
            for g in list {
                gid(&mut w, g);
            }
        }
        w.finish()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn nodes_are_named_from_the_topic_namespace() {
        assert_eq!(node_of("/latentam"), ("/".into(), "latentam".into()));
        assert_eq!(
            node_of("/robot1/latentam/"),
            ("/robot1".into(), "latentam".into())
        );
        assert_eq!(node_of("mapper"), ("/".into(), "mapper".into()));
    }

    #[test]
    fn the_layout_follows_the_distribution() {
        assert_eq!(gid_bytes(Some("humble")), 24);
        assert_eq!(gid_bytes(Some("jazzy")), 16);
        assert_eq!(gid_bytes(None), 16);
    }

    /// Field by field: a 16-byte Gid, one node with its names, one
    /// reader and two writers, at CDR's alignments.
    #[test]
    fn encodes_participant_entities_info() {
        let g = |b: u8| [b; 16];
        for gid_len in [16usize, 24] {
            let m = ParticipantEntities {
                participant: g(1),
                namespace: "/",
                name: "latentam",
                readers: &[g(2)],
                writers: &[g(3), g(4)],
                gid_bytes: gid_len,
            }
            .encode();
            let mut want = vec![0u8, 1, 0, 0];
            let gid = |want: &mut Vec<u8>, b: u8| {
                want.extend([b; 16]);
                want.extend(vec![0u8; gid_len - 16]);
            };
            gid(&mut want, 1);
            want.extend(1u32.to_le_bytes());
            want.extend(2u32.to_le_bytes());
            want.extend(b"/\0");
            want.extend([0, 0]); // to a multiple of 4
            want.extend(9u32.to_le_bytes());
            want.extend(b"latentam\0");
            want.extend([0, 0, 0]);
            want.extend(1u32.to_le_bytes());
            gid(&mut want, 2);
            want.extend(2u32.to_le_bytes());
            gid(&mut want, 3);
            gid(&mut want, 4);
            assert_eq!(m, want, "Gid of {gid_len} bytes");
        }
    }
}

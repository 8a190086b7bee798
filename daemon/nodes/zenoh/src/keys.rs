//! rmw_zenoh's names (its `docs/design.md`): data keys
//! `<domain>/<fully qualified topic>/<dds type>/<type hash>`, liveliness
//! tokens `@ros2_lv/<domain>/<zid>/<node id>/<entity id>/<kind>/<enclave>/
//! <namespace>/<node>[/<topic>/<type>/<hash>/<qos>]` (names mangled: `/` →
//! `%`, empty → `%`), and the attachment of every sample (sequence number,
//! Unix time in ns, publisher GID).
//!
//! The layout for several robots is ROS 2's own: one namespace per robot
//! (`/robot1`), so robot 1's map is `0/robot1/slam/map/...` and a map
//! merger on the operator's side subscribes to `0/*/slam/map/<type>/<hash>`
//! and publishes `0/map_merged/...` without any change to the bridge.

use sha2::{Digest, Sha256};

/// The hermetic prefix of every rmw_zenoh liveliness token.
pub const ADMIN_SPACE: &str = "@ros2_lv";
/// The node the bridge declares itself as (`ros2 node list` shows it).
pub const NODE_NAME: &str = "smokenav_zenoh";

/// What kind of graph entity a token declares.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum EntityKind {
    Node,
    Publisher,
    Subscription,
}

impl EntityKind {
    pub fn as_str(self) -> &'static str {
        match self {
            EntityKind::Node => "NN",
            EntityKind::Publisher => "MP",
            EntityKind::Subscription => "MS",
        }
    }
}

/// A ROS 2 QoS profile, as far as the bridge offers them.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Qos {
    pub transient_local: bool,
    pub depth: u32,
}

impl Qos {
    /// rmw_zenoh's compact form: each field left empty when it is rmw_zenoh's
    /// default (reliable, volatile, keep last 42, infinite durations,
    /// automatic liveliness): `rel:dur:hist,depth:dl_s,dl_ns:ls_s,ls_ns:lv,lv_s,lv_ns`.
    pub fn keyexpr(self) -> String {
        let durability = if self.transient_local { "1" } else { "" };
        let depth = if self.depth == 42 {
            String::new()
        } else {
            self.depth.to_string()
        };
        format!(":{durability}:,{depth}:,:,:,,")
    }
}

/// `/` → `%` (rmw_zenoh's mangling); an empty name is `%`.
pub fn mangle(name: &str) -> String {
    if name.is_empty() {
        "%".into()
    } else {
        name.replace('/', "%")
    }
}

/// `/robot1` + `/laser/scan` → `/robot1/laser/scan`.
pub fn qualified(namespace: &str, ros2_topic: &str) -> String {
    format!("{}{}", namespace.trim_end_matches('/'), ros2_topic)
}

/// The data key of a topic: `0/robot1/laser/scan/sensor_msgs::msg::dds_::LaserScan_/RIHS01_…`.
pub fn topic_key(domain: u32, qualified_topic: &str, dds_type: &str, hash: &str) -> String {
    format!(
        "{domain}/{}/{dds_type}/{hash}",
        qualified_topic.trim_start_matches('/')
    )
}

/// The bridge's node token.
pub fn node_token(domain: u32, zid: &str, namespace: &str) -> String {
    format!(
        "{ADMIN_SPACE}/{domain}/{zid}/0/0/NN/%/{}/{NODE_NAME}",
        mangle(namespace)
    )
}

/// A publisher's or subscription's token (entity ids from 1 up).
#[allow(clippy::too_many_arguments)]
pub fn entity_token(
    domain: u32,
    zid: &str,
    entity_id: u32,
    kind: EntityKind,
    namespace: &str,
    qualified_topic: &str,
    dds_type: &str,
    hash: &str,
    qos: Qos,
) -> String {
    format!(
        "{ADMIN_SPACE}/{domain}/{zid}/0/{entity_id}/{}/%/{}/{NODE_NAME}/{}/{dds_type}/{hash}/{}",
        kind.as_str(),
        mangle(namespace),
        mangle(qualified_topic),
        qos.keyexpr()
    )
}

/// A node token's namespace and node name, if `key` is one.
pub fn parse_node_token(key: &str) -> Option<NodeToken> {
    let parts: Vec<&str> = key.split('/').collect();
    if parts.len() != 9 || parts[0] != ADMIN_SPACE || parts[5] != "NN" {
        return None;
    }
    Some(NodeToken {
        domain: parts[1].parse().ok()?,
        zid: parts[2].to_owned(),
        namespace: unmangle(parts[7]),
        node: parts[8].to_owned(),
    })
}

/// `%robot1` → `/robot1`; `%` → empty.
pub fn unmangle(s: &str) -> String {
    if s == "%" {
        String::new()
    } else {
        s.replace('%', "/")
    }
}

/// A node's liveliness token, parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct NodeToken {
    pub domain: u32,
    pub zid: String,
    pub namespace: String,
    pub node: String,
}

/// The publisher GID: 16 bytes derived from its liveliness token, as
/// rmw_zenoh derives it (it uses XXH3-128; any stable 16-byte digest of the
/// token is as unique, and receivers only compare GIDs).
pub fn gid(token: &str) -> [u8; 16] {
    let d = Sha256::digest(token.as_bytes());
    let mut g = [0u8; 16];
    g.copy_from_slice(&d[..16]);
    g
}

/// The attachment rmw_zenoh sends with every sample: sequence number (i64
/// LE), source time in ns since the Unix epoch (i64 LE), GID length (1
/// byte, 16) and the GID.
pub const ATTACHMENT_LEN: usize = 8 + 8 + 1 + 16;

pub fn attachment(seq: i64, unix_ns: i64, gid: &[u8; 16]) -> [u8; ATTACHMENT_LEN] {
    let mut a = [0u8; ATTACHMENT_LEN];
    a[..8].copy_from_slice(&seq.to_le_bytes());
    a[8..16].copy_from_slice(&unix_ns.to_le_bytes());
    a[16] = 16;
    a[17..].copy_from_slice(gid);
    a
}

/// An attachment's fields, if it is one.
pub fn parse_attachment(a: &[u8]) -> Option<(i64, i64, [u8; 16])> {
    if a.len() != ATTACHMENT_LEN || a[16] != 16 {
        return None;
    }
    let seq = i64::from_le_bytes(a[..8].try_into().ok()?);
    let t = i64::from_le_bytes(a[8..16].try_into().ok()?);
    Some((seq, t, a[17..].try_into().ok()?))
}

#[cfg(test)]
mod tests {
    use super::*;

    const HASH: &str = "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18";

    /// The examples of rmw_zenoh's design document.
    #[test]
    fn keys_and_tokens_are_rmw_zenohs() {
        assert_eq!(
            topic_key(
                0,
                &qualified("/robot1", "/chatter"),
                "std_msgs::msg::dds_::String_",
                HASH
            ),
            format!("0/robot1/chatter/std_msgs::msg::dds_::String_/{HASH}")
        );
        assert_eq!(
            topic_key(
                0,
                &qualified("", "/chatter"),
                "std_msgs::msg::dds_::String_",
                HASH
            ),
            format!("0/chatter/std_msgs::msg::dds_::String_/{HASH}")
        );
        let zid = "8b20917502ee955ac4476e0266340d5c";
        let t = entity_token(
            2,
            zid,
            10,
            EntityKind::Publisher,
            "",
            "/chatter",
            "std_msgs::msg::dds_::String_",
            HASH,
            Qos {
                transient_local: false,
                depth: 7,
            },
        );
        assert_eq!(
            t,
            format!(
                "@ros2_lv/2/{zid}/0/10/MP/%/%/smokenav_zenoh/%chatter/std_msgs::msg::dds_::String_/{HASH}/::,7:,:,:,,"
            )
        );
        assert_eq!(
            Qos {
                transient_local: true,
                depth: 1
            }
            .keyexpr(),
            ":1:,1:,:,:,,"
        );
        let n = node_token(0, zid, "/robot1");
        assert_eq!(
            n,
            format!("@ros2_lv/0/{zid}/0/0/NN/%/%robot1/smokenav_zenoh")
        );
        let p = parse_node_token(&n).unwrap();
        assert_eq!(
            (p.namespace.as_str(), p.domain, p.node.as_str()),
            ("/robot1", 0, NODE_NAME)
        );
        assert!(parse_node_token(&t).is_none());
    }

    #[test]
    fn attachment_round_trips() {
        let g = gid("x");
        let a = attachment(7, 1_700_000_000_000_000_000, &g);
        assert_eq!(a.len(), 33);
        assert_eq!(
            parse_attachment(&a),
            Some((7, 1_700_000_000_000_000_000, g))
        );
        assert_eq!(parse_attachment(&a[..32]), None);
    }
}

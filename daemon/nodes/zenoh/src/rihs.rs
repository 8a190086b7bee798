//! ROS 2 type hashes (REP-2016, `RIHS01_<sha256>`), computed from the
//! ros2msg definitions the recordings carry: rmw_zenoh puts the hash in
//! every key expression and liveliness token, and a subscriber on another
//! machine only matches a publisher whose hash equals its own.
//!
//! The hash is the SHA-256 of the type description's JSON (the type, then
//! every type it refers to, sorted by name; fields as name + type id,
//! capacity, string capacity, nested type name; constants and defaults left
//! out), written as Python's `json.dumps` with `(", ", ": ")` separators —
//! what `rosidl_generator_type_description` writes.

use sha2::{Digest, Sha256};
use smokenav_platform_recording::schema::MsgDef;
use std::collections::BTreeMap;
use std::fmt::Write;
use thiserror::Error;

/// A definition this module cannot describe.
#[derive(Debug, Error, PartialEq, Eq)]
pub enum HashError {
    #[error("{ty}: line `{line}`: {reason}")]
    Field {
        ty: &'static str,
        line: String,
        reason: &'static str,
    },
    #[error("{ty}: `{owner}` uses `{nested}`, which is not among its dependencies")]
    MissingDep {
        ty: &'static str,
        owner: String,
        nested: String,
    },
}

// type_description_interfaces/msg/FieldType
const NESTED: u8 = 1;
const STRING: u8 = 17;
const WSTRING: u8 = 18;
const BOUNDED_STRING: u8 = 21;
const BOUNDED_WSTRING: u8 = 22;
const ARRAY: u8 = 48;
const BOUNDED_SEQUENCE: u8 = 96;
const UNBOUNDED_SEQUENCE: u8 = 144;

fn primitive_id(t: &str) -> Option<u8> {
    Some(match t {
        "int8" => 2,
        // rosidl maps a .msg `char` to uint8 and `byte` to octet.
        "uint8" | "char" => 3,
        "int16" => 4,
        "uint16" => 5,
        "int32" => 6,
        "uint32" => 7,
        "int64" => 8,
        "uint64" => 9,
        "float32" => 10,
        "float64" => 11,
        "bool" => 15,
        "byte" => 16,
        "string" => STRING,
        "wstring" => WSTRING,
        _ => return None,
    })
}

struct Field {
    name: String,
    type_id: u8,
    capacity: u64,
    string_capacity: u64,
    nested: String,
}

/// `pkg/Type` (as written in a field) → `pkg/msg/Type`.
fn full_name(t: &str, own_pkg: &str) -> String {
    match t.split_once('/') {
        Some((pkg, ty)) => format!("{pkg}/msg/{ty}"),
        None if t == "Header" => "std_msgs/msg/Header".into(),
        None => format!("{own_pkg}/msg/{t}"),
    }
}

fn fields(def: &MsgDef) -> Result<Vec<Field>, HashError> {
    let pkg = def.name.split('/').next().unwrap_or("");
    let mut out = Vec::new();
    for raw in def.text.lines() {
        let line = raw.split('#').next().unwrap_or("").trim();
        if line.is_empty() {
            continue;
        }
        let bad = |reason| HashError::Field {
            ty: def.name,
            line: raw.to_owned(),
            reason,
        };
        let mut parts = line.split_whitespace();
        let (Some(ty), Some(name)) = (parts.next(), parts.next()) else {
            return Err(bad("expected `TYPE NAME`"));
        };
        // A constant (`uint8 FREE=0`) is not a field.
        if name.contains('=') || parts.next().is_some_and(|p| p.starts_with('=')) {
            continue;
        }
        let (base, array) = match ty.split_once('[') {
            Some((b, rest)) => (
                b,
                Some(rest.strip_suffix(']').ok_or_else(|| bad("unclosed `[`"))?),
            ),
            None => (ty, None),
        };
        let (base, string_capacity) = match base.split_once("<=") {
            Some((b, n)) => (b, n.parse().map_err(|_| bad("bad string bound"))?),
            None => (base, 0),
        };
        let (mut type_id, nested) = match primitive_id(base) {
            Some(id) => (id, String::new()),
            None => (NESTED, full_name(base, pkg)),
        };
        if string_capacity > 0 {
            type_id = match type_id {
                STRING => BOUNDED_STRING,
                WSTRING => BOUNDED_WSTRING,
                _ => return Err(bad("a bound on a type that is no string")),
            };
        }
        let mut capacity = 0;
        match array {
            None => {}
            Some("") => type_id += UNBOUNDED_SEQUENCE,
            Some(n) => match n.strip_prefix("<=") {
                Some(b) => {
                    type_id += BOUNDED_SEQUENCE;
                    capacity = b.parse().map_err(|_| bad("bad sequence bound"))?;
                }
                None => {
                    type_id += ARRAY;
                    capacity = n.parse().map_err(|_| bad("bad array size"))?;
                }
            },
        }
        out.push(Field {
            name: name.to_owned(),
            type_id,
            capacity,
            string_capacity,
            nested,
        });
    }
    if out.is_empty() {
        // rosidl gives an empty message one placeholder member.
        out.push(Field {
            name: "structure_needs_at_least_one_member".into(),
            type_id: 3,
            capacity: 0,
            string_capacity: 0,
            nested: String::new(),
        });
    }
    Ok(out)
}

fn describe(out: &mut String, name: &str, fields: &[Field]) {
    let _ = write!(out, "{{\"type_name\": \"{name}\", \"fields\": [");
    for (i, f) in fields.iter().enumerate() {
        if i > 0 {
            out.push_str(", ");
        }
        let _ = write!(
            out,
            "{{\"name\": \"{}\", \"type\": {{\"type_id\": {}, \"capacity\": {}, \"string_capacity\": {}, \"nested_type_name\": \"{}\"}}}}",
            f.name, f.type_id, f.capacity, f.string_capacity, f.nested
        );
    }
    out.push_str("]}");
}

/// The hashed JSON of `def` (exposed for tests).
pub fn hashed_json(def: &MsgDef) -> Result<String, HashError> {
    let own = fields(def)?;
    let mut refs: BTreeMap<&'static str, Vec<Field>> = BTreeMap::new();
    let mut stack: Vec<&MsgDef> = def.deps.to_vec();
    while let Some(d) = stack.pop() {
        if refs.contains_key(d.name) {
            continue;
        }
        refs.insert(d.name, fields(d)?);
        stack.extend(d.deps.iter().copied());
    }
    // Every nested type must be described (a missing dependency would hash silently wrong).
    for (owner, fs) in std::iter::once((def.name, &own)).chain(refs.iter().map(|(n, f)| (*n, f))) {
        for f in fs.iter().filter(|f| !f.nested.is_empty()) {
            if !refs.contains_key(f.nested.as_str()) {
                return Err(HashError::MissingDep {
                    ty: def.name,
                    owner: owner.to_owned(),
                    nested: f.nested.clone(),
                });
            }
        }
    }
    let mut json = String::from("{\"type_description\": ");
    describe(&mut json, def.name, &own);
    json.push_str(", \"referenced_type_descriptions\": [");
    for (i, (name, fs)) in refs.iter().enumerate() {
        if i > 0 {
            json.push_str(", ");
        }
        describe(&mut json, name, fs);
    }
    json.push_str("]}");
    Ok(json)
}

/// `RIHS01_<64 hex>` of `def`.
pub fn type_hash(def: &MsgDef) -> Result<String, HashError> {
    let digest = Sha256::digest(hashed_json(def)?.as_bytes());
    let mut s = String::from("RIHS01_");
    for b in digest {
        let _ = write!(s, "{b:02x}");
    }
    Ok(s)
}

/// The DDS name of `pkg/msg/Type` as rmw_zenoh keys carry it: `pkg::msg::dds_::Type_`.
pub fn dds_type_name(ros2_type: &str) -> String {
    match ros2_type.rsplit_once('/') {
        Some((pkg_msg, ty)) => format!("{}::dds_::{ty}_", pkg_msg.replace('/', "::")),
        None => format!("{ros2_type}_"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use smokenav_platform_recording::schema;

    /// rmw_zenoh's design document gives the `chatter` key:
    /// `std_msgs::msg::dds_::String_/RIHS01_df668c74…`.
    #[test]
    fn std_msgs_string_hash_is_the_one_rmw_zenoh_documents() {
        static STRING_MSG: MsgDef = MsgDef {
            name: "std_msgs/msg/String",
            text: "string data\n",
            deps: &[],
        };
        assert_eq!(
            type_hash(&STRING_MSG).unwrap(),
            "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18"
        );
        assert_eq!(
            dds_type_name("std_msgs/msg/String"),
            "std_msgs::msg::dds_::String_"
        );
    }

    /// The hash `rosbags`' Jazzy type store gives sensor_msgs/msg/LaserScan
    /// (the e2e test compares every catalog type with it).
    #[test]
    fn laser_scan_hash_is_the_ros2_one() {
        assert_eq!(
            type_hash(&schema::LASER_SCAN).unwrap(),
            "RIHS01_64c191398013af96509d518dac71d5164f9382553fce5c1f8cca5be7924bd828"
        );
    }

    #[test]
    fn laser_scan_describes_header_and_time_sorted() {
        let j = hashed_json(&schema::LASER_SCAN).unwrap();
        let time = j
            .find("\"type_name\": \"builtin_interfaces/msg/Time\"")
            .unwrap();
        let header = j.find("\"type_name\": \"std_msgs/msg/Header\"").unwrap();
        assert!(time < header, "{j}");
        assert!(j.contains("{\"name\": \"ranges\", \"type\": {\"type_id\": 154, \"capacity\": 0"));
    }

    #[test]
    fn a_dependency_left_out_is_an_error() {
        static BAD: MsgDef = MsgDef {
            name: "x_msgs/msg/Bad",
            text: "std_msgs/Header header\n",
            deps: &[],
        };
        assert!(matches!(type_hash(&BAD), Err(HashError::MissingDep { .. })));
    }

    #[test]
    fn every_schema_hashes() {
        for def in schema::ALL {
            let h = type_hash(def).unwrap_or_else(|e| panic!("{e}"));
            assert_eq!(h.len(), 7 + 64);
        }
    }
}

//! 2D g2o files: `VERTEX_SE2 id x y θ`, `EDGE_SE2 i j dx dy dθ I11 I12 I13
//! I22 I23 I33` (the upper triangle of the information matrix, row by row)
//! and `FIX id`. Lines starting with `#` are comments.
//!
//! Input is distrusted: a malformed line, a vertex declared twice, an edge
//! naming a vertex that does not exist, an information matrix that is not
//! positive definite and records of other (3D, landmark) types are errors
//! with the line number. Lines are capped at [`MAX_LINE_BYTES`], the graph at
//! [`MAX_VERTICES`] vertices and [`MAX_EDGES`] edges.

use super::pose_graph::{Edge, Information, PoseGraph, is_positive_definite};
use smokenav_shared_types::Pose2;
use std::collections::HashMap;
use std::io::BufRead;

pub const MAX_LINE_BYTES: usize = 4096;
pub const MAX_VERTICES: usize = 5_000_000;
pub const MAX_EDGES: usize = 20_000_000;

#[derive(Debug, Clone, PartialEq, thiserror::Error)]
pub enum G2oError {
    #[error("line {line}: {record} expects {expected} fields after the tag, got {got}")]
    Fields {
        line: usize,
        record: &'static str,
        expected: usize,
        got: usize,
    },
    #[error("line {line}: field {index} ({what}) is not a finite number: {text:?}")]
    Number {
        line: usize,
        index: usize,
        what: &'static str,
        text: String,
    },
    #[error("line {line}: vertex {id} is declared twice")]
    DuplicateVertex { line: usize, id: u64 },
    #[error("line {line}: edge refers to vertex {id}, which no VERTEX_SE2 before it declares")]
    DanglingEdge { line: usize, id: u64 },
    #[error("line {line}: edge {from} → {to} connects a vertex to itself")]
    SelfEdge { line: usize, from: u64, to: u64 },
    #[error("line {line}: the information matrix of edge {from} → {to} is not positive definite")]
    NotPositiveDefinite { line: usize, from: u64, to: u64 },
    #[error(
        "line {line}: {tag} records are not supported (only 2D pose graphs: VERTEX_SE2, EDGE_SE2, FIX)"
    )]
    Unsupported { line: usize, tag: String },
    #[error("line {line}: longer than {MAX_LINE_BYTES} bytes")]
    LineTooLong { line: usize },
    #[error("line {line}: not UTF-8")]
    NotUtf8 { line: usize },
    #[error("line {line}: more than {limit} {what}")]
    TooLarge {
        line: usize,
        what: &'static str,
        limit: usize,
    },
    #[error("read error after line {line}: {message}")]
    Io { line: usize, message: String },
}

/// Reads a 2D g2o graph. Vertices keep their file ids; `FIX` marks fixed vertices.
pub fn read<R: BufRead>(input: R) -> Result<PoseGraph, G2oError> {
    let mut graph = PoseGraph::new();
    let mut index: HashMap<u64, usize> = HashMap::new();
    let mut fixes: Vec<(usize, u64)> = Vec::new();
    let mut buf = Vec::new();
    let mut line_no = 0usize;
    let mut input = input;
    loop {
        buf.clear();
        let n = std::io::Read::take(&mut input, MAX_LINE_BYTES as u64 + 1)
            .read_until(b'\n', &mut buf)
            .map_err(|e| G2oError::Io {
                line: line_no,
                message: e.to_string(),
            })?;
        if n == 0 {
            break;
        }
        line_no += 1;
        if buf.len() > MAX_LINE_BYTES && !buf.ends_with(b"\n") {
            return Err(G2oError::LineTooLong { line: line_no });
        }
        let text = std::str::from_utf8(&buf).map_err(|_| G2oError::NotUtf8 { line: line_no })?;
        let mut fields = text.split_whitespace();
        let Some(tag) = fields.next() else { continue };
        if tag.starts_with('#') {
            continue;
        }
        let rest: Vec<&str> = fields.collect();
        let line = line_no;
        let want = |record: &'static str, expected: usize| {
            if rest.len() == expected {
                Ok(())
            } else {
                Err(G2oError::Fields {
                    line,
                    record,
                    expected,
                    got: rest.len(),
                })
            }
        };
        let num = |i: usize, what: &'static str| -> Result<f64, G2oError> {
            rest[i]
                .parse::<f64>()
                .ok()
                .filter(|v| v.is_finite())
                .ok_or_else(|| G2oError::Number {
                    line,
                    index: i + 1,
                    what,
                    text: rest[i].chars().take(40).collect(),
                })
        };
        let id = |i: usize| -> Result<u64, G2oError> {
            rest[i].parse::<u64>().map_err(|_| G2oError::Number {
                line,
                index: i + 1,
                what: "vertex id",
                text: rest[i].chars().take(40).collect(),
            })
        };
        match tag {
            "VERTEX_SE2" => {
                want("VERTEX_SE2", 4)?;
                let v = id(0)?;
                let pose = Pose2::new(num(1, "x")?, num(2, "y")?, num(3, "theta")?);
                if index.contains_key(&v) {
                    return Err(G2oError::DuplicateVertex { line, id: v });
                }
                if graph.len() >= MAX_VERTICES {
                    return Err(G2oError::TooLarge {
                        line,
                        what: "vertices",
                        limit: MAX_VERTICES,
                    });
                }
                index.insert(v, graph.add_vertex(v, pose));
            }
            "EDGE_SE2" => {
                want("EDGE_SE2", 11)?;
                let (a, b) = (id(0)?, id(1)?);
                let z = Pose2::new(num(2, "dx")?, num(3, "dy")?, num(4, "dtheta")?);
                let mut u = [0.0; 6];
                for (k, v) in u.iter_mut().enumerate() {
                    *v = num(5 + k, "information")?;
                }
                let information: Information =
                    [[u[0], u[1], u[2]], [u[1], u[3], u[4]], [u[2], u[4], u[5]]];
                let from = *index
                    .get(&a)
                    .ok_or(G2oError::DanglingEdge { line, id: a })?;
                let to = *index
                    .get(&b)
                    .ok_or(G2oError::DanglingEdge { line, id: b })?;
                if from == to {
                    return Err(G2oError::SelfEdge {
                        line,
                        from: a,
                        to: b,
                    });
                }
                if !is_positive_definite(&information) {
                    return Err(G2oError::NotPositiveDefinite {
                        line,
                        from: a,
                        to: b,
                    });
                }
                if graph.edges().len() >= MAX_EDGES {
                    return Err(G2oError::TooLarge {
                        line,
                        what: "edges",
                        limit: MAX_EDGES,
                    });
                }
                graph.add_edge(Edge {
                    from,
                    to,
                    measurement: z,
                    information,
                    robust: false,
                });
            }
            "FIX" => {
                if rest.is_empty() {
                    return Err(G2oError::Fields {
                        line,
                        record: "FIX",
                        expected: 1,
                        got: 0,
                    });
                }
                for i in 0..rest.len() {
                    fixes.push((line, id(i)?));
                }
            }
            other => {
                return Err(G2oError::Unsupported {
                    line,
                    tag: other.chars().take(40).collect(),
                });
            }
        }
    }
    // FIX may come before or after its vertex.
    for (line, v) in fixes {
        let i = *index
            .get(&v)
            .ok_or(G2oError::DanglingEdge { line, id: v })?;
        graph.set_fixed(i, true);
    }
    Ok(graph)
}

/// Writes the graph in the same format (full `f64` precision, so reading it back gives the same graph).
pub fn write<W: std::io::Write>(graph: &PoseGraph, mut out: W) -> std::io::Result<()> {
    let ids = graph.ids();
    for (i, p) in graph.poses().iter().enumerate() {
        writeln!(out, "VERTEX_SE2 {} {} {} {}", ids[i], p.x, p.y, p.theta)?;
    }
    for e in graph.edges() {
        let m = &e.information;
        writeln!(
            out,
            "EDGE_SE2 {} {} {} {} {} {} {} {} {} {} {}",
            ids[e.from],
            ids[e.to],
            e.measurement.x,
            e.measurement.y,
            e.measurement.theta,
            m[0][0],
            m[0][1],
            m[0][2],
            m[1][1],
            m[1][2],
            m[2][2]
        )?;
    }
    for (i, id) in ids.iter().enumerate() {
        if graph.is_fixed(i) {
            writeln!(out, "FIX {id}")?;
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    const SMALL: &str = "# a triangle\n\
        VERTEX_SE2 0 0 0 0\n\
        VERTEX_SE2 1 1.0 0.0 0.0\n\
        VERTEX_SE2 5 1.0 1.0 1.5707963\n\
        EDGE_SE2 0 1 1 0 0 100 0 0 100 0 400\n\
        EDGE_SE2 1 5 0 1 1.5707963 100 0 0 100 0 400\n\
        EDGE_SE2 5 0 -1 1 1.5707963 100 0 0 100 0 400\n\
        FIX 0\n";

    fn err(text: &str) -> G2oError {
        read(text.as_bytes()).unwrap_err()
    }

    #[test]
    fn graph_round_trips_through_text() {
        let g = read(SMALL.as_bytes()).unwrap();
        assert_eq!(g.len(), 3);
        assert_eq!(g.edges().len(), 3);
        assert_eq!(g.ids(), &[0, 1, 5]);
        assert!(g.is_fixed(0) && !g.is_fixed(2));
        let mut text = Vec::new();
        write(&g, &mut text).unwrap();
        let back = read(&text[..]).unwrap();
        assert_eq!(back.poses(), g.poses());
        assert_eq!(back.edges(), g.edges());
        assert!(back.is_fixed(0));
    }

    #[test]
    fn malformed_line_is_reported_with_its_number() {
        let e = err("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 0 zero 0\n");
        assert_eq!(
            e,
            G2oError::Number {
                line: 2,
                index: 3,
                what: "y",
                text: "zero".into()
            }
        );
        assert!(e.to_string().starts_with("line 2:"), "{e}");
        assert!(matches!(
            err("VERTEX_SE2 0 0 0\n"),
            G2oError::Fields {
                line: 1,
                got: 3,
                ..
            }
        ));
        assert!(matches!(
            err("VERTEX_SE2 0 0 0 nan\n"),
            G2oError::Number { line: 1, .. }
        ));
        assert!(matches!(
            err("VERTEX_SE2 -3 0 0 0\n"),
            G2oError::Number {
                line: 1,
                what: "vertex id",
                ..
            }
        ));
        assert!(matches!(
            err("\n\nVERTEX_SE3:QUAT 0 0 0 0 0 0 0 1\n"),
            G2oError::Unsupported { line: 3, .. }
        ));
    }

    #[test]
    fn dangling_edge_id_is_reported_with_its_line() {
        let e = err("VERTEX_SE2 0 0 0 0\n# gap\nEDGE_SE2 0 9 1 0 0 1 0 0 1 0 1\n");
        assert_eq!(e, G2oError::DanglingEdge { line: 3, id: 9 });
        assert!(matches!(
            err("VERTEX_SE2 0 0 0 0\nFIX 4\n"),
            G2oError::DanglingEdge { line: 2, id: 4 }
        ));
        assert!(matches!(
            err("VERTEX_SE2 0 0 0 0\nVERTEX_SE2 0 1 0 0\n"),
            G2oError::DuplicateVertex { line: 2, id: 0 }
        ));
    }

    #[test]
    fn non_positive_definite_information_is_reported_with_its_line() {
        let base = "VERTEX_SE2 0 0 0 0\nVERTEX_SE2 1 1 0 0\n";
        // Indefinite (off-diagonal larger than the diagonal), and singular (zero rotation weight).
        for info in ["1 5 0 1 0 1", "1 0 0 1 0 0", "-1 0 0 1 0 1"] {
            let e = err(&format!("{base}EDGE_SE2 0 1 1 0 0 {info}\n"));
            assert_eq!(
                e,
                G2oError::NotPositiveDefinite {
                    line: 3,
                    from: 0,
                    to: 1
                },
                "{info}"
            );
        }
    }

    #[test]
    fn overlong_and_binary_lines_are_refused() {
        let long = format!(
            "VERTEX_SE2 0 0 0 0\n# {}\n",
            "x".repeat(MAX_LINE_BYTES + 10)
        );
        assert_eq!(err(&long), G2oError::LineTooLong { line: 2 });
        assert_eq!(
            read(&b"VERTEX_SE2 0 0 0 \xff\n"[..]).unwrap_err(),
            G2oError::NotUtf8 { line: 1 }
        );
    }
}

//! A log-odds occupancy octree laid out like OctoMap's `OcTree` (Hornung et
//! al. 2013): 16 levels, keys `floor(c / res) + 2¹⁵` per axis, child index
//! `x + 2y + 4z` of the key bits at each level, inner nodes holding their
//! children's maximum, clamped updates, and pruning of eight identical leaf
//! children into their parent. A node's eight children live together in one
//! block of a vector (a free list reuses pruned blocks), so a descent reads
//! one block per level and steady-state updates do not allocate.

use crate::logodds::ClampLogOdds;
use std::io::{self, BufRead, Read, Write};

/// Tree depth: OctoMap's 16 levels.
pub const DEPTH: u32 = 16;
/// Key of the coordinate 0.
pub const KEY_ORIGIN: i64 = 1 << (DEPTH - 1);
/// `Node::kids` of a leaf.
const LEAF: u32 = u32::MAX;
/// `Node::kids` of a child slot with no node (unknown space).
const ABSENT: u32 = u32::MAX - 1;
/// Node id of the root; other nodes are `block · 8 + child`.
const ROOT: u32 = u32::MAX;

/// A voxel key at the finest level.
pub type Key = [u16; 3];

/// Packs a key into one integer (for key sets).
pub fn pack(k: Key) -> u64 {
    (k[0] as u64) | ((k[1] as u64) << 16) | ((k[2] as u64) << 32)
}

pub fn unpack(v: u64) -> Key {
    [v as u16, (v >> 16) as u16, (v >> 32) as u16]
}

#[derive(Debug, Clone, Copy)]
struct Node {
    logodds: f32,
    /// Index of the block holding the eight children, or [`LEAF`], or
    /// [`ABSENT`] for an empty child slot.
    kids: u32,
}

const ABSENT_NODE: Node = Node {
    logodds: 0.0,
    kids: ABSENT,
};

/// One leaf: the cube of `size` finest voxels per side from `key` (its
/// lowest corner key), and its log-odds.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Leaf {
    pub key: Key,
    pub size: u32,
    pub logodds: f32,
}

#[derive(Debug, Clone)]
pub struct Octree {
    resolution: f64,
    clamp: ClampLogOdds,
    root: Node,
    blocks: Vec<[Node; 8]>,
    free_blocks: Vec<u32>,
    /// Nodes in use, root included.
    live: usize,
    /// Scratch path of one descent (node ids).
    path: Vec<u32>,
    /// The nodes along the last key searched, reused by the next search of a
    /// nearby key (a cone's voxels come column by column); cleared by any
    /// change to the tree.
    cache: SearchCache,
}

#[derive(Debug, Clone, Copy)]
struct SearchCache {
    key: Key,
    /// `nodes[d]` is the node id at depth `d` on `key`'s path, for `d < len`.
    nodes: [u32; DEPTH as usize + 1],
    len: usize,
}

impl SearchCache {
    const EMPTY: SearchCache = SearchCache {
        key: [0; 3],
        nodes: [0; DEPTH as usize + 1],
        len: 0,
    };
}

#[derive(Debug, thiserror::Error)]
pub enum BtError {
    #[error("reading the .bt file: {0}")]
    Io(#[from] io::Error),
    #[error(".bt header, line {line}: {reason}")]
    Header { line: usize, reason: String },
    #[error(".bt data: {0}")]
    Data(String),
}

/// What an export wrote.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct BtStats {
    /// Nodes in the file (the header's `size`).
    pub nodes: usize,
    pub occupied_leaves: usize,
    pub free_leaves: usize,
}

impl Octree {
    pub fn new(resolution: f64, clamp: ClampLogOdds) -> Self {
        Self {
            resolution,
            clamp,
            root: Node {
                logodds: 0.0,
                kids: LEAF,
            },
            blocks: Vec::new(),
            free_blocks: Vec::new(),
            live: 1,
            path: Vec::with_capacity(DEPTH as usize + 1),
            cache: SearchCache::EMPTY,
        }
    }

    pub fn resolution(&self) -> f64 {
        self.resolution
    }

    pub fn clamping(&self) -> ClampLogOdds {
        self.clamp
    }

    /// The key of a coordinate, `None` outside the tree's ±2¹⁵ voxels.
    pub fn key_of(&self, c: f64) -> Option<u16> {
        let k = (c / self.resolution).floor();
        if !k.is_finite() {
            return None;
        }
        let k = k as i64 + KEY_ORIGIN;
        (0..=u16::MAX as i64).contains(&k).then_some(k as u16)
    }

    pub fn key(&self, p: [f64; 3]) -> Option<Key> {
        Some([self.key_of(p[0])?, self.key_of(p[1])?, self.key_of(p[2])?])
    }

    /// Centre coordinate of a key along one axis.
    pub fn coord(&self, k: u16) -> f64 {
        (k as i64 - KEY_ORIGIN) as f64 * self.resolution + self.resolution / 2.0
    }

    fn child_pos(key: Key, depth: u32) -> usize {
        let bit = DEPTH - 1 - depth;
        (((key[0] >> bit) & 1) | (((key[1] >> bit) & 1) << 1) | (((key[2] >> bit) & 1) << 2))
            as usize
    }

    fn node(&self, id: u32) -> Node {
        if id == ROOT {
            self.root
        } else {
            self.blocks[(id / 8) as usize][(id % 8) as usize]
        }
    }

    fn node_mut(&mut self, id: u32) -> &mut Node {
        if id == ROOT {
            &mut self.root
        } else {
            &mut self.blocks[(id / 8) as usize][(id % 8) as usize]
        }
    }

    fn alloc_block(&mut self) -> u32 {
        if let Some(i) = self.free_blocks.pop() {
            self.blocks[i as usize] = [ABSENT_NODE; 8];
            i
        } else {
            self.blocks.push([ABSENT_NODE; 8]);
            (self.blocks.len() - 1) as u32
        }
    }

    /// The log-odds of the leaf covering `key`, `None` if unknown.
    pub fn search(&self, key: Key) -> Option<f32> {
        let mut node = self.root;
        if node.kids == LEAF {
            return None;
        }
        for depth in 0..DEPTH {
            if node.kids == LEAF {
                return Some(node.logodds);
            }
            let child = self.blocks[node.kids as usize][Self::child_pos(key, depth)];
            if child.kids == ABSENT {
                return None;
            }
            node = child;
        }
        Some(node.logodds)
    }

    /// Adds a hit (`occupied`) or a miss at `key` with the tree's clamping.
    pub fn integrate(&mut self, key: Key, occupied: bool) {
        let delta = if occupied {
            self.clamp.hit
        } else {
            self.clamp.miss
        };
        self.integrate_logodds(key, delta);
    }

    /// Adds `delta` at `key` unless the leaf is already at the bound in that
    /// direction (OctoMap's shortcut: no change).
    pub fn integrate_logodds(&mut self, key: Key, delta: f32) {
        if let Some(l) = self.search_cached(key)
            && self.clamp.saturated(l, delta > 0.0)
        {
            return;
        }
        self.update(key, delta);
    }

    /// [`Octree::search`] starting from the deepest node the last searched
    /// key shares with this one.
    fn search_cached(&mut self, key: Key) -> Option<f32> {
        if self.root.kids == LEAF {
            return None;
        }
        let c = &mut self.cache;
        let diff = (c.key[0] ^ key[0]) | (c.key[1] ^ key[1]) | (c.key[2] ^ key[2]);
        // Nodes at depths 0..=shared lie on both paths.
        let shared = diff.leading_zeros() as usize;
        let mut depth = if c.len == 0 {
            c.nodes[0] = ROOT;
            0
        } else {
            shared.min(c.len - 1)
        };
        c.key = key;
        let mut id = c.nodes[depth];
        loop {
            c.len = depth + 1;
            let node = if id == ROOT {
                self.root
            } else {
                self.blocks[(id / 8) as usize][(id % 8) as usize]
            };
            if node.kids == LEAF {
                return (id != ROOT).then_some(node.logodds);
            }
            let pos = Self::child_pos(key, depth as u32);
            if self.blocks[node.kids as usize][pos].kids == ABSENT {
                return None;
            }
            depth += 1;
            id = node.kids * 8 + pos as u32;
            c.nodes[depth] = id;
        }
    }

    /// Adds `delta` (log-odds) at `key`, clamped; expands pruned leaves on
    /// the way down, prunes and refreshes inner maxima on the way up.
    pub fn update(&mut self, key: Key, delta: f32) {
        self.cache.len = 0;
        let mut path = std::mem::take(&mut self.path);
        path.clear();
        let mut id = ROOT;
        let mut just_created = false;
        for depth in 0..DEPTH {
            let pos = Self::child_pos(key, depth);
            let node = self.node(id);
            if node.kids == LEAF {
                let b = self.alloc_block();
                self.node_mut(id).kids = b;
                if id != ROOT && !just_created {
                    // A pruned leaf: its eight children inherit its value.
                    self.blocks[b as usize] = [Node {
                        logodds: node.logodds,
                        kids: LEAF,
                    }; 8];
                    self.live += 8;
                }
            }
            let b = self.node(id).kids;
            let slot = &mut self.blocks[b as usize][pos];
            just_created = slot.kids == ABSENT;
            if just_created {
                *slot = Node {
                    logodds: 0.0,
                    kids: LEAF,
                };
                self.live += 1;
            }
            path.push(id);
            id = b * 8 + pos as u32;
        }
        let clamp = self.clamp;
        let leaf = self.node_mut(id);
        leaf.logodds = clamp.add(leaf.logodds, delta);
        // A node whose value and shape did not change leaves its ancestors as
        // they were: stop there.
        for &parent in path.iter().rev() {
            if !self.refresh(parent) {
                break;
            }
        }
        self.path = path;
    }

    /// Sets an inner node to its children's maximum, or prunes eight
    /// identical leaf children into it. Returns whether the node changed.
    fn refresh(&mut self, id: u32) -> bool {
        let node = self.node(id);
        if node.kids == LEAF {
            return false;
        }
        let kids = self.blocks[node.kids as usize];
        let mut max = f32::NEG_INFINITY;
        let mut prunable = id != ROOT;
        for k in &kids {
            if k.kids == ABSENT {
                prunable = false;
                continue;
            }
            max = max.max(k.logodds);
            if k.kids != LEAF || k.logodds != kids[0].logodds {
                prunable = false;
            }
        }
        let n = self.node_mut(id);
        n.logodds = max;
        if prunable {
            n.kids = LEAF;
            self.free_blocks.push(node.kids);
            self.live -= 8;
        }
        prunable || max != node.logodds
    }

    /// Nodes in use, root included.
    pub fn node_count(&self) -> usize {
        self.live
    }

    /// Bytes the live nodes take (the root and the blocks in use).
    pub fn memory_bytes(&self) -> usize {
        std::mem::size_of::<Node>()
            + (self.blocks.len() - self.free_blocks.len()) * std::mem::size_of::<[Node; 8]>()
    }

    /// Calls `f` for every leaf (pruned leaves once, with their size).
    pub fn for_each_leaf(&self, mut f: impl FnMut(Leaf)) {
        if self.root.kids == LEAF {
            return;
        }
        let mut stack: Vec<(Node, u32, Key)> = vec![(self.root, 0, [0, 0, 0])];
        while let Some((node, depth, base)) = stack.pop() {
            if node.kids == LEAF {
                f(Leaf {
                    key: base,
                    size: 1 << (DEPTH - depth),
                    logodds: node.logodds,
                });
                continue;
            }
            let half = 1u32 << (DEPTH - 1 - depth);
            for (i, &c) in self.blocks[node.kids as usize].iter().enumerate() {
                if c.kids == ABSENT {
                    continue;
                }
                let mut k = base;
                for (axis, kk) in k.iter_mut().enumerate() {
                    if i & (1 << axis) != 0 {
                        *kk += half as u16;
                    }
                }
                stack.push((c, depth + 1, k));
            }
        }
    }

    /// Calls `f(key, logodds)` for every finest voxel the leaves cover.
    pub fn for_each_voxel(&self, mut f: impl FnMut(Key, f32)) {
        self.for_each_leaf(|l| {
            for dz in 0..l.size {
                for dy in 0..l.size {
                    for dx in 0..l.size {
                        f(
                            [
                                l.key[0] + dx as u16,
                                l.key[1] + dy as u16,
                                l.key[2] + dz as u16,
                            ],
                            l.logodds,
                        );
                    }
                }
            }
        });
    }

    /// Writes the tree in OctoMap's binary format (`.bt`, read by
    /// `octomap::OcTree::readBinary` and the `octomap-tools`): a text header,
    /// then per inner node, depth first from the root, two bytes with two bits
    /// per child (children 0–3, then 4–7). For child `i`, written as the pair
    /// (bit `2i`, bit `2i + 1`) of its byte: (0, 0) unknown, (0, 1) occupied
    /// leaf, (1, 0) free leaf, (1, 1) inner node. As OctoMap
    /// does when writing, values become maximum-likelihood first (occupied iff
    /// log-odds > 0) and eight equal leaf children merge into their parent.
    pub fn write_bt(&self, w: &mut impl Write) -> io::Result<BtStats> {
        let ml = self.max_likelihood(ROOT);
        let mut stats = BtStats {
            nodes: 0,
            occupied_leaves: 0,
            free_leaves: 0,
        };
        let root_children = match &ml {
            Ml::Inner(c) => Some(c),
            _ => None,
        };
        if let Some(c) = root_children {
            stats.nodes = 1;
            count(c, &mut stats);
        }
        write!(
            w,
            "# Octomap OcTree binary file\nid OcTree\nsize {}\nres {}\ndata\n",
            stats.nodes, self.resolution
        )?;
        if let Some(c) = root_children {
            let mut buf = Vec::with_capacity(stats.nodes * 2);
            encode(c, &mut buf);
            w.write_all(&buf)?;
        }
        Ok(stats)
    }

    fn max_likelihood(&self, id: u32) -> Ml {
        let node = self.node(id);
        if node.kids == LEAF {
            return if id == ROOT {
                Ml::Unknown
            } else {
                Ml::Leaf(node.logodds > 0.0)
            };
        }
        let kids: [Ml; 8] = std::array::from_fn(|i| {
            if self.blocks[node.kids as usize][i].kids == ABSENT {
                Ml::Unknown
            } else {
                self.max_likelihood(node.kids * 8 + i as u32)
            }
        });
        if id != ROOT
            && let Ml::Leaf(first) = kids[0]
            && kids.iter().all(|k| matches!(k, Ml::Leaf(v) if *v == first))
        {
            return Ml::Leaf(first);
        }
        Ml::Inner(Box::new(kids))
    }

    /// Reads a `.bt` file (as written by OctoMap or [`Octree::write_bt`]);
    /// leaves take the clamping bounds, as OctoMap's reader gives them.
    /// Distrusts its input: the node count is checked against `size`.
    pub fn read_bt(r: &mut impl BufRead, clamp: ClampLogOdds) -> Result<Self, BtError> {
        let mut line = String::new();
        let mut lineno = 0;
        let mut size: Option<usize> = None;
        let mut res: Option<f64> = None;
        let header_err = |line: usize, reason: String| BtError::Header { line, reason };
        loop {
            line.clear();
            if (&mut *r).take(256).read_line(&mut line)? == 0 {
                return Err(header_err(lineno + 1, "file ends before `data`".into()));
            }
            lineno += 1;
            let l = line.trim_end();
            if lineno == 1 {
                if !l.starts_with("# Octomap OcTree binary file") {
                    return Err(header_err(1, format!("not an OctoMap binary file: {l:?}")));
                }
                continue;
            }
            if l.starts_with('#') {
                continue;
            }
            let (k, v) = l.split_once(' ').unwrap_or((l, ""));
            match k {
                "id" if v != "OcTree" => {
                    return Err(header_err(
                        lineno,
                        format!("tree type {v:?}, expected OcTree"),
                    ));
                }
                "id" => {}
                "size" => {
                    size =
                        Some(v.parse().map_err(|_| {
                            header_err(lineno, format!("size {v:?} is not a number"))
                        })?)
                }
                "res" => {
                    let x: f64 = v
                        .parse()
                        .map_err(|_| header_err(lineno, format!("res {v:?} is not a number")))?;
                    if !(x.is_finite() && x > 0.0) {
                        return Err(header_err(lineno, format!("res {x} is not positive")));
                    }
                    res = Some(x);
                }
                "data" => break,
                _ => return Err(header_err(lineno, format!("unknown key {k:?}"))),
            }
        }
        let size = size.ok_or_else(|| header_err(lineno, "no `size` line".into()))?;
        let res = res.ok_or_else(|| header_err(lineno, "no `res` line".into()))?;
        let mut tree = Octree::new(res, clamp);
        if size == 0 {
            return Ok(tree);
        }
        // Depth first, as written; the stack holds (node, depth) still to read.
        let mut stack = vec![(ROOT, 0u32)];
        let mut read = 1usize;
        while let Some((n, depth)) = stack.pop() {
            let mut bytes = [0u8; 2];
            r.read_exact(&mut bytes)
                .map_err(|e| BtError::Data(format!("after {read} nodes: {e}")))?;
            let b = tree.alloc_block();
            tree.node_mut(n).kids = b;
            let mut inner = Vec::new();
            for i in 0..8 {
                let byte = bytes[i / 4];
                let bits = (byte >> ((i % 4) * 2)) & 0b11;
                let value = match bits {
                    0b00 => continue,
                    0b10 => clamp.max,
                    0b01 => clamp.min,
                    _ => {
                        if depth + 1 >= DEPTH {
                            return Err(BtError::Data(format!(
                                "an inner node below the {DEPTH} levels (after {read} nodes)"
                            )));
                        }
                        clamp.max
                    }
                };
                tree.blocks[b as usize][i] = Node {
                    logodds: value,
                    kids: LEAF,
                };
                tree.live += 1;
                let c = b * 8 + i as u32;
                read += 1;
                if read > size {
                    return Err(BtError::Data(format!(
                        "more nodes than the header's size {size}"
                    )));
                }
                if bits == 0b11 {
                    inner.push(c);
                }
            }
            // Children are read in order 0..8: push them reversed.
            for &c in inner.iter().rev() {
                stack.push((c, depth + 1));
            }
        }
        if read != size {
            return Err(BtError::Data(format!(
                "{read} nodes read, the header says {size}"
            )));
        }
        tree.refresh_all(ROOT);
        Ok(tree)
    }

    fn refresh_all(&mut self, id: u32) {
        let b = self.node(id).kids;
        if b == LEAF {
            return;
        }
        let mut max = f32::NEG_INFINITY;
        for i in 0..8 {
            if self.blocks[b as usize][i].kids != ABSENT {
                let c = b * 8 + i as u32;
                self.refresh_all(c);
                max = max.max(self.node(c).logodds);
            }
        }
        self.node_mut(id).logodds = max;
    }
}

/// A node as the export sees it.
enum Ml {
    Unknown,
    Leaf(bool),
    Inner(Box<[Ml; 8]>),
}

fn count(kids: &[Ml; 8], s: &mut BtStats) {
    for k in kids {
        match k {
            Ml::Unknown => {}
            Ml::Leaf(true) => {
                s.nodes += 1;
                s.occupied_leaves += 1;
            }
            Ml::Leaf(false) => {
                s.nodes += 1;
                s.free_leaves += 1;
            }
            Ml::Inner(c) => {
                s.nodes += 1;
                count(c, s);
            }
        }
    }
}

fn encode(kids: &[Ml; 8], out: &mut Vec<u8>) {
    let mut bytes = [0u8; 2];
    for (i, k) in kids.iter().enumerate() {
        let bits = match k {
            // (bit 2i, bit 2i + 1) as the value `bit2i | bit2i+1 << 1`.
            Ml::Unknown => 0b00,
            Ml::Leaf(true) => 0b10,
            Ml::Leaf(false) => 0b01,
            Ml::Inner(_) => 0b11,
        };
        bytes[i / 4] |= bits << ((i % 4) * 2);
    }
    out.extend_from_slice(&bytes);
    for k in kids {
        if let Ml::Inner(c) = k {
            encode(c, out);
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::logodds::Clamping;

    fn tree() -> Octree {
        Octree::new(0.05, Clamping::default().into())
    }

    #[test]
    fn keys_follow_octomap() {
        let t = tree();
        assert_eq!(t.key_of(0.0), Some(32768));
        assert_eq!(t.key_of(0.049), Some(32768));
        assert_eq!(t.key_of(-0.001), Some(32767));
        assert!((t.coord(32768) - 0.025).abs() < 1e-12);
        assert_eq!(t.key_of(1e9), None);
        assert_eq!(t.key_of(f64::NAN), None);
    }

    #[test]
    fn updates_clamp_and_inner_nodes_hold_the_maximum() {
        let mut t = tree();
        let k = t.key([1.0, 2.0, 0.3]).unwrap();
        for _ in 0..10 {
            t.integrate(k, true);
        }
        assert_eq!(t.search(k), Some(t.clamping().max));
        let k2 = t.key([1.05, 2.0, 0.3]).unwrap();
        t.integrate(k2, false);
        assert!((t.search(k2).unwrap() - t.clamping().miss).abs() < 1e-6);
        assert_eq!(t.root.logodds, t.clamping().max);
        assert_eq!(t.search(t.key([5.0, 5.0, 5.0]).unwrap()), None);
    }

    #[test]
    fn eight_saturated_siblings_prune_and_expand_again() {
        let mut t = tree();
        let base = [32768u16, 32768, 32768];
        for i in 0..8u16 {
            let k = [
                base[0] + (i & 1),
                base[1] + ((i >> 1) & 1),
                base[2] + ((i >> 2) & 1),
            ];
            for _ in 0..10 {
                t.integrate(k, false);
            }
        }
        // 16 levels of path to one parent of 8 pruned leaves: 16 nodes.
        assert_eq!(t.node_count(), 16, "pruned into the parent");
        let mut leaves = Vec::new();
        t.for_each_leaf(|l| leaves.push(l));
        assert_eq!(leaves.len(), 1);
        assert_eq!(leaves[0].size, 2);
        assert_eq!(leaves[0].key, base);
        // A hit in the pruned cube expands it and leaves the siblings free.
        t.integrate(base, true);
        assert_eq!(t.node_count(), 24);
        assert_eq!(
            t.search([base[0] + 1, base[1], base[2]]),
            Some(t.clamping().min)
        );
        let mut n = 0;
        t.for_each_voxel(|_, _| n += 1);
        assert_eq!(n, 8);
    }

    #[test]
    fn random_updates_match_a_dense_reference_through_pruning_and_expansion() {
        // A 4³ cube of voxels, hammered with hits and misses in a fixed
        // pseudo-random order: every voxel's value must equal the clamped sum
        // a plain array keeps, whatever was pruned and expanded on the way.
        let mut t = tree();
        let c = t.clamping();
        let mut reference = [0f32; 64];
        let mut known = [false; 64];
        let mut x: u64 = 0x9e37_79b9_7f4a_7c15;
        let mut pruned_seen = false;
        for _ in 0..20_000 {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            let i = (x % 64) as usize;
            // Mostly misses, so regions saturate free and prune, then hits break them up.
            let occupied = (x >> 8).is_multiple_of(5);
            let k = [
                32768 + (i & 3) as u16,
                32768 + ((i >> 2) & 3) as u16,
                32768 + (i >> 4) as u16,
            ];
            t.integrate(k, occupied);
            let delta = if occupied { c.hit } else { c.miss };
            reference[i] = c.add(reference[i], delta);
            known[i] = true;
            let mut leaves = 0;
            t.for_each_leaf(|_| leaves += 1);
            pruned_seen |= leaves < known.iter().filter(|k| **k).count();
        }
        for i in 0..64 {
            let k = [
                32768 + (i & 3) as u16,
                32768 + ((i >> 2) & 3) as u16,
                32768 + (i >> 4) as u16,
            ];
            assert_eq!(t.search(k), known[i].then_some(reference[i]), "voxel {i}");
        }
        assert!(
            pruned_seen,
            "the sequence never pruned: the test would prove nothing"
        );
        // Inner nodes hold the maximum of what lies below.
        let max = reference.iter().copied().fold(f32::NEG_INFINITY, f32::max);
        assert_eq!(t.root.logodds, max);
    }

    #[test]
    fn bt_export_reads_back_with_the_same_occupied_voxels() {
        let mut t = tree();
        let mut occupied = std::collections::BTreeSet::new();
        for i in 0..40 {
            let p = [
                i as f64 * 0.05,
                (i % 7) as f64 * 0.05,
                (i % 3) as f64 * 0.05,
            ];
            let k = t.key(p).unwrap();
            t.integrate(k, i % 4 != 0);
            if i % 4 != 0 {
                occupied.insert(k);
            }
        }
        let mut bytes = Vec::new();
        let stats = t.write_bt(&mut bytes).unwrap();
        assert_eq!(stats.occupied_leaves, occupied.len());
        let text = String::from_utf8_lossy(&bytes[..60]);
        assert!(text.starts_with("# Octomap OcTree binary file\nid OcTree\nsize "));
        let back = Octree::read_bt(&mut &bytes[..], Clamping::default().into()).unwrap();
        let mut got = std::collections::BTreeSet::new();
        back.for_each_voxel(|k, l| {
            if l > 0.0 {
                got.insert(k);
            }
        });
        assert_eq!(got, occupied);
        assert_eq!(back.node_count(), stats.nodes);
    }

    #[test]
    fn bt_bits_are_octomaps_pairs() {
        // One occupied voxel at key (2¹⁵, 2¹⁵, 2¹⁵) and a free one at x + 1
        // under the same parent: the last level's byte has child 0 occupied
        // (bit 1) and child 1 free (bit 2), as OctoMap's writeBinaryNode sets
        // child1to4[0] = 0, [1] = 1 for occupied and [2] = 1, [3] = 0 for free.
        let mut t = tree();
        let k = [32768u16, 32768, 32768];
        t.integrate(k, true);
        t.integrate([k[0] + 1, k[1], k[2]], false);
        let mut bytes = Vec::new();
        t.write_bt(&mut bytes).unwrap();
        let data = &bytes[bytes.len() - 2..];
        assert_eq!(data, &[0b0000_0110, 0]);
    }

    #[test]
    fn bt_reader_rejects_bad_files() {
        let c = Clamping::default().into();
        let bad = |s: &[u8]| Octree::read_bt(&mut &s[..], c).unwrap_err().to_string();
        assert!(bad(b"hello\n").contains("not an OctoMap"));
        assert!(bad(b"# Octomap OcTree binary file\nid ColorOcTree\n").contains("OcTree"));
        assert!(
            bad(b"# Octomap OcTree binary file\nid OcTree\nsize 3\nres 0.1\ndata\n\x03")
                .contains("after 1 nodes")
        );
        assert!(
            bad(b"# Octomap OcTree binary file\nid OcTree\nsize 2\nres 0.1\ndata\n\x05\x00")
                .contains("more nodes")
        );
        assert!(bad(b"# Octomap OcTree binary file\nid OcTree\nres -1\n").contains("not positive"));
    }
}

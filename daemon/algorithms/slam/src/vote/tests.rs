//! The vote with real members on their threads, in the test room.

use super::member::{FaultKind, MemberFault};
use super::*;
use crate::testkit::scan_at;
use smokenav_platform_config::SlamBackendKind as K;

fn cfg(members: &[K], lockstep: bool) -> SlamSection {
    let mut c = SlamSection {
        particles: 4,
        backend: K::Vote,
        ..SlamSection::default()
    };
    c.vote.members = members.to_vec();
    c.vote.lockstep = lockstep;
    c.vote.fuse_period_s = 0.05;
    c.vote.stall_timeout_s = 0.5;
    c
}

/// Drives 1.6 m along the room's x axis, feeding exact odometry.
fn drive(v: &mut VoteSlam, scans: usize) -> Vec<SlamUpdate> {
    (0..scans)
        .map(|i| {
            let truth = Pose2::new(-1.5 + 0.04 * i as f64, -1.5, 0.0);
            v.process(
                &scan_at(&truth, 1_000_000_000 + i as u64 * 100_000_000),
                &truth,
            )
        })
        .collect()
}

fn wait_for(v: &VoteSlam, what: &str, mut f: impl FnMut() -> bool) {
    let deadline = Instant::now() + Duration::from_secs(30);
    while !f() {
        assert!(
            Instant::now() < deadline,
            "timed out waiting for {what}: {:?}",
            v.status()
                .members
                .iter()
                .map(|m| (m.name, m.health.to_string(), m.drops))
                .collect::<Vec<_>>()
        );
        std::thread::sleep(Duration::from_millis(20));
    }
}

#[test]
fn three_members_vote_in_lockstep_and_align_to_the_reference() {
    let mut v = VoteSlam::new(
        &cfg(&[K::Rbpf, K::Graph, K::Fuzzy], true),
        &BackendOptions {
            keep_trajectory: true,
            ..BackendOptions::default()
        },
        None,
    )
    .unwrap();
    v.set_initial_pose(Pose2::new(-1.5, -1.5, 0.0));
    let ups = drive(&mut v, 40);
    let last = ups.last().unwrap();
    assert!(
        (last.pose.x - (-1.5 + 0.04 * 39.0)).abs() < 0.1 && (last.pose.y + 1.5).abs() < 0.1,
        "fused pose {:?}",
        last.pose
    );
    let map = v.map().expect("a fused map");
    let st = v.status();
    assert_eq!(st.fuses, 1);
    for m in &st.members {
        assert_eq!(m.health, MemberHealth::In, "{}: {}", m.name, m.health);
        assert_eq!(m.drops, 0, "lockstep drops nothing");
        let a = m
            .alignment
            .unwrap_or_else(|| panic!("{} not aligned", m.name));
        assert!(a.residual_m < 0.1, "{}: residual {}", m.name, a.residual_m);
    }
    // The south wall (y = −3) is in the fused map, free space in front of it.
    let (cx, cy) = map.world_to_cell(-1.0, -3.0).unwrap();
    let near = (cy.saturating_sub(1)..=cy + 1).any(|y| map.get(cx, y) == Some(100));
    assert!(near, "wall missing from the fused map");
    let (fx, fy) = map.world_to_cell(-1.0, -2.0).unwrap();
    assert_eq!(map.get(fx, fy), Some(0));
    assert_eq!(v.trajectory().len(), 40);
}

#[test]
fn a_panicking_member_is_out_and_the_vote_goes_on() {
    let fault = MemberFault {
        member: K::Fuzzy,
        kind: FaultKind::Panic,
        after_scans: 3,
    };
    let mut v = VoteSlam::new(
        &cfg(&[K::Rbpf, K::Graph, K::Fuzzy], false),
        &BackendOptions::default(),
        Some(fault),
    )
    .unwrap();
    drive(&mut v, 10);
    wait_for(&v, "fuzzy to be out", || {
        v.status()
            .members
            .iter()
            .any(|m| m.name == "fuzzy" && matches!(m.health, MemberHealth::Panicked(_)))
    });
    let before = v.status().fuses;
    drive(&mut v, 10);
    wait_for(&v, "a vote after the panic", || {
        v.status().fuses > before && v.map().is_some()
    });
    let st = v.status();
    let names: Vec<_> = st
        .members
        .iter()
        .filter(|m| m.health.is_out())
        .map(|m| m.name)
        .collect();
    assert_eq!(names, ["fuzzy"]);
    let mut out = Vec::new();
    v.metrics(&mut |n, x| out.push((n, x)));
    assert!(out.contains(&("vote_out_fuzzy", 1.0)), "{out:?}");
    assert!(out.contains(&("vote_out_rbpf", 0.0)), "{out:?}");
    // Health names the member (through the trait, as the process reads it).
    let said = v.health_condition().unwrap_or_default();
    assert!(
        said.starts_with("vote: member fuzzy out (panicked"),
        "{said}"
    );
}

#[test]
fn a_stalled_member_drops_scans_and_never_holds_the_others() {
    let fault = MemberFault {
        member: K::Graph,
        kind: FaultKind::Stall,
        after_scans: 2,
    };
    let mut c = cfg(&[K::Rbpf, K::Graph], false);
    c.vote.queue = 2;
    let mut v = VoteSlam::new(&c, &BackendOptions::default(), Some(fault)).unwrap();
    // Scans keep coming while the member hangs in its third: process() keeps returning.
    let deadline = Instant::now() + Duration::from_secs(60);
    let mut i = 0u64;
    loop {
        let truth = Pose2::new(-1.5 + 0.01 * i as f64, -1.5, 0.0);
        v.process(&scan_at(&truth, 1_000_000_000 + i * 100_000_000), &truth);
        i += 1;
        let st = v.status();
        let graph = st.members.iter().find(|m| m.name == "graph").unwrap();
        if matches!(graph.health, MemberHealth::Stalled(_)) && graph.drops > 0 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "graph never stalled: {}",
            graph.health
        );
        std::thread::sleep(Duration::from_millis(20));
    }
    let st = v.status();
    let rbpf = st.members.iter().find(|m| m.name == "rbpf").unwrap();
    assert_eq!(rbpf.health, MemberHealth::In);
    let mut out = Vec::new();
    v.metrics(&mut |n, x| out.push((n, x)));
    assert!(out.contains(&("vote_out_graph", 1.0)), "{out:?}");
    assert!(out.contains(&("vote_members_out", 1.0)), "{out:?}");
    // The fused pose follows the member still running.
    let u = v.predict(1_000_000_000 + i * 100_000_000, &Pose2::new(0.5, -1.5, 0.0));
    assert!((u.pose.x - 2.0).abs() < 0.3, "{:?}", u.pose);
}

#[test]
fn fault_knob_parses_and_names_bad_parts() {
    let f: MemberFault = "graph:stall:40".parse().unwrap();
    assert_eq!(
        f,
        MemberFault {
            member: K::Graph,
            kind: FaultKind::Stall,
            after_scans: 40
        }
    );
    let e = "karto:stall:4".parse::<MemberFault>().unwrap_err();
    assert!(e.contains("karto"), "{e}");
    let e = "graph:hang:4".parse::<MemberFault>().unwrap_err();
    assert!(e.contains("hang"), "{e}");
    assert!("graph:stall".parse::<MemberFault>().is_err());
}

/// The pipeline's front-end match reaches the graph member with its scan: the
/// graph then takes the given (corrected) odometry as the scan's pose instead
/// of matching the scan again, which would move it.
#[test]
fn the_front_end_match_is_forwarded_to_the_graph_member() {
    let graph_pose_error = |forward: bool| -> f64 {
        let mut v = VoteSlam::new(
            &cfg(&[K::Graph, K::Rbpf], true),
            &BackendOptions::default(),
            None,
        )
        .unwrap();
        v.set_initial_pose(Pose2::new(-1.5, -1.5, 0.0));
        let mut worst = 0.0f64;
        for i in 0..20 {
            let truth = Pose2::new(-1.5 + 0.04 * i as f64, -1.5, 0.0);
            // Odometry 3 cm off to the side on every other scan: the graph's
            // own matcher would pull the pose back onto the walls.
            let odom = Pose2::new(truth.x, truth.y + 0.03 * (i % 2) as f64, 0.0);
            if forward {
                v.frontend_match(&Tracked {
                    pose: odom,
                    score: Some(0.9),
                    stale_odometry: false,
                    degenerate_directions: 0,
                    covariance: Matrix3::from_diagonal_element(1e-4),
                    squared_turn: 0.0,
                    side_turn: 0.0,
                });
            }
            v.process(
                &scan_at(&truth, 1_000_000_000 + i as u64 * 100_000_000),
                &odom,
            );
            let (u, o) = v.members[0].shared.lock().update.expect("graph updated");
            assert_eq!(o, odom);
            worst = worst.max((u.pose.x - odom.x).hypot(u.pose.y - odom.y));
        }
        worst
    };
    let own = graph_pose_error(false);
    assert!(
        own > 0.005,
        "the graph's own matcher left the odometry: {own}"
    );
    let shared = graph_pose_error(true);
    assert!(
        shared < 1e-6,
        "with the shared match the pose is the odometry: {shared}"
    );
}

/// A 4 × 3 m room at 5 cm: walls occupied, inside free.
fn room() -> OccupancyGrid {
    use smokenav_platform_map::{FREE, OCCUPIED};
    let (w, h) = (80, 60);
    let mut g = OccupancyGrid::new(w, h, 0.05, [0.0, 0.0, 0.0]);
    for y in 0..h {
        for x in 0..w {
            let wall = x < 2 || y < 2 || x >= w - 2 || y >= h - 2 || (x == 40 && y < 30);
            g.cells[y * w + x] = if wall { OCCUPIED } else { FREE };
        }
    }
    g
}

/// The members' maps as the fuser's inputs, one revision each; member `k` out when `out(k)`.
fn inputs_of(members: Vec<OccupancyGrid>, out: impl Fn(usize) -> bool) -> Vec<FuseInput> {
    members
        .into_iter()
        .enumerate()
        .map(|(k, m)| FuseInput {
            map: Some((Arc::new(m), 1)),
            below: None,
            out: out(k),
            weight: 1.0,
        })
        .collect()
}

/// One forced fused update of `inputs` under `section`: the fuser after it.
fn fused_once(section: VoteSection, inputs: &[FuseInput]) -> Fuser {
    let mut f = Fuser::new(
        VoteParams {
            section,
            fault: None,
        },
        inputs.len(),
    );
    assert!(f.fuse(inputs, &SonarShare::default(), true));
    f
}

#[test]
fn a_member_that_maps_in_height_decides_out_of_the_plane_and_abstains_in_it() {
    use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};
    let (w, at, split) = (80, 20 * 80 + 60, 45 * 80 + 20);
    let mut members: Vec<OccupancyGrid> = vec![room(); 4];
    // In the plane at `split`: two laser-plane members free, one occupied;
    // the height member occupied. Counted, 2 : 2 would be a tie (occupied).
    members[2].cells[split] = OCCUPIED;
    members[3].cells[split] = OCCUPIED;
    // Out of the plane at `at`: the three laser-plane members see free floor
    // (their beams pass over a low box), the height member an obstacle.
    let mut below = OccupancyGrid::new(w, 60, 0.05, [0.0, 0.0, 0.0]);
    below.cells.fill(UNKNOWN);
    below.cells[at] = OCCUPIED;
    let inputs: Vec<FuseInput> = members
        .into_iter()
        .enumerate()
        .map(|(i, m)| FuseInput {
            map: Some((Arc::new(m), 1)),
            below: (i == 3).then(|| Arc::new(below.clone())),
            out: false,
            weight: 1.0,
        })
        .collect();
    let section = VoteSection {
        members: vec![K::Rbpf, K::Graph, K::Fuzzy, K::Projected],
        ..VoteSection::default()
    };
    let mut f = fused_once(section, &inputs);
    let fused = f.out.map.clone().unwrap();
    assert_eq!(fused.cells[at], OCCUPIED, "the low box");
    assert_eq!(fused.cells[split], FREE, "two of three in the plane");
    assert_eq!(f.out.out_of_plane_cells, 1);
    // Without its out-of-plane map the same member is one more laser-plane
    // voter: the box goes, and the split is a tie.
    let mut plain = inputs;
    plain[3].below = None;
    f.fuse(&plain, &SonarShare::default(), true);
    let fused = f.out.map.clone().unwrap();
    assert_eq!(fused.cells[at], FREE);
    assert_eq!(fused.cells[split], OCCUPIED);
}

#[test]
fn majority_reference_takes_the_references_cell_where_the_members_split() {
    use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};
    // At `split` the reference sees free floor, member 1 a wall, member 2
    // nothing: a three-way split. At `two` members 1 and 2 agree on a wall
    // the reference lacks: a majority, whatever the rule.
    let (split, two) = (20 * 80 + 20, 45 * 80 + 60);
    let mut members: Vec<OccupancyGrid> = vec![room(); 3];
    members[1].cells[split] = OCCUPIED;
    members[2].cells[split] = UNKNOWN;
    members[1].cells[two] = OCCUPIED;
    members[2].cells[two] = OCCUPIED;
    let mut inputs = inputs_of(members, |_| false);
    let fuse = |rule: VoteRule, inputs: &[FuseInput]| {
        let section = VoteSection {
            rule,
            ..VoteSection::default()
        };
        fused_once(section, inputs).out.map.clone().unwrap()
    };
    let paper = fuse(VoteRule::Majority, &inputs);
    assert_eq!(paper.cells[split], OCCUPIED, "the paper: doubt is a wall");
    assert_eq!(paper.cells[two], OCCUPIED);
    let by_ref = fuse(VoteRule::MajorityReference, &inputs);
    assert_eq!(by_ref.cells[split], FREE, "the reference's cell");
    assert_eq!(by_ref.cells[two], OCCUPIED, "a majority still wins");
    // With the reference out (its map still sets the frame), the first
    // member still voting decides: member 1's wall.
    inputs[0].out = true;
    let out = fuse(VoteRule::MajorityReference, &inputs);
    assert_eq!(out.cells[split], OCCUPIED);
    let mut m1 = (*inputs[1].map.as_ref().unwrap().0).clone();
    m1.cells[split] = FREE;
    inputs[1].map = Some((Arc::new(m1), 2));
    let out = fuse(VoteRule::MajorityReference, &inputs);
    assert_eq!(out.cells[split], FREE, "member 1's free floor");
}

/// The fused map of one vote under `rule`, the other keys at their defaults.
fn fused_map(rule: VoteRule, inputs: &[FuseInput]) -> Arc<OccupancyGrid> {
    let section = VoteSection {
        rule,
        ..VoteSection::default()
    };
    fused_once(section, inputs).out.map.clone().unwrap()
}

#[test]
fn corroborated_draws_a_split_cell_only_where_another_member_has_a_wall_beside_it() {
    use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};
    // Three-way splits (reference free, member 1 a wall, member 2 nothing):
    // at `lone` member 1's wall stands alone (a phantom); at `beside`
    // member 2 has a wall one cell east (the same wall drawn a cell off).
    let (w, lone, beside) = (80, 20 * 80 + 20, 30 * 80 + 20);
    let mut members: Vec<OccupancyGrid> = vec![room(); 3];
    for at in [lone, beside] {
        members[1].cells[at] = OCCUPIED;
        members[2].cells[at] = UNKNOWN;
    }
    members[2].cells[beside + 1] = OCCUPIED;
    let members_free = members.clone();
    let inputs = inputs_of(members, |_| false);
    let fuse = |rule: VoteRule| fused_map(rule, &inputs);
    let paper = fuse(VoteRule::Majority);
    assert_eq!(
        [paper.cells[lone], paper.cells[beside]],
        [OCCUPIED; 2],
        "the paper: every doubt is a wall"
    );
    let c = fuse(VoteRule::Corroborated);
    assert_eq!(c.cells[lone], FREE, "a lone wall is not drawn");
    assert_eq!(
        c.cells[beside], OCCUPIED,
        "a wall another member has beside it is"
    );
    // Where a majority exists the rules agree.
    let room_wall = (60 - 1) * w + 10;
    assert_eq!(members_free[0].cells[room_wall], OCCUPIED);
    assert_eq!(c.cells[room_wall], OCCUPIED);
}

#[test]
fn corroborated_reference_keeps_the_reference_where_members_split_but_not_its_lone_walls() {
    use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};
    // Three-way splits on an 80-wide room:
    // - `lone`: the reference draws a wall, member 1 free, member 2 nothing,
    //   and no other member has a wall near it (a phantom of the reference);
    // - `beside`: the same, but member 2 has a wall a cell east (the same
    //   wall, drawn a cell off);
    // - `other`: member 1 draws a wall where the reference sees free floor
    //   and member 2 nothing, with member 2's wall beside it.
    let (w, lone, beside, other) = (80, 20 * 80 + 20, 30 * 80 + 20, 40 * 80 + 20);
    let mut members: Vec<OccupancyGrid> = vec![room(); 3];
    for at in [lone, beside] {
        members[0].cells[at] = OCCUPIED;
        members[1].cells[at] = FREE;
        members[2].cells[at] = UNKNOWN;
    }
    members[2].cells[beside + 1] = OCCUPIED;
    members[1].cells[other] = OCCUPIED;
    members[2].cells[other] = UNKNOWN;
    members[2].cells[other + 1] = OCCUPIED;
    let inputs = inputs_of(members, |_| false);
    let fuse = |rule: VoteRule| fused_map(rule, &inputs);
    let c = fuse(VoteRule::CorroboratedReference);
    assert_eq!(
        c.cells[lone], FREE,
        "the reference's lone wall is not drawn"
    );
    assert_eq!(
        c.cells[beside], OCCUPIED,
        "a reference wall another member has beside it is"
    );
    assert_eq!(
        c.cells[other], FREE,
        "without a majority the reference's free floor stands"
    );
    // `corroborated` would draw the last one (member 1's wall has member 2's
    // beside it), `majority-reference` the first.
    assert_eq!(fuse(VoteRule::Corroborated).cells[other], OCCUPIED);
    assert_eq!(fuse(VoteRule::MajorityReference).cells[lone], OCCUPIED);
    // Where a majority exists the rules agree.
    let room_wall = (60 - 1) * w + 10;
    assert_eq!(c.cells[room_wall], OCCUPIED);
    assert_eq!(c.cells[10 * w + 10], FREE);
}

#[test]
fn with_a_member_out_two_maps_do_not_vote_their_union() {
    use smokenav_platform_map::{FREE, OCCUPIED};
    // Member 1 draws the partition (x = 40) one cell east: the kind of
    // offset two members' walls have everywhere. Member 2 is out. Two votes
    // never split in a majority, and the paper's "no majority → occupied"
    // would draw both copies of every wall.
    let (w, h) = (80, 60);
    let mut members: Vec<OccupancyGrid> = vec![room(); 3];
    for y in 2..30 {
        members[1].cells[y * w + 40] = FREE;
        members[1].cells[y * w + 41] = OCCUPIED;
    }
    let inputs = inputs_of(members, |k| k == 2);
    for rule in [
        VoteRule::Majority,
        VoteRule::MajorityReference,
        VoteRule::Corroborated,
        VoteRule::CorroboratedReference,
    ] {
        let section = VoteSection {
            rule,
            ..VoteSection::default()
        };
        let f = fused_once(section, &inputs);
        let fused = f.out.map.clone().unwrap();
        assert!(f.out.alignments[1].is_some_and(|a| a.transform.translation_norm() < 0.01));
        for y in 2..30 {
            assert_eq!(
                fused.cells[y * w + 40],
                OCCUPIED,
                "{rule:?} y {y}: the reference's wall"
            );
            assert_eq!(
                fused.cells[y * w + 41],
                FREE,
                "{rule:?} y {y}: one copy, not two"
            );
        }
        assert_eq!(
            fused.cells[(h - 1) * w + 10],
            OCCUPIED,
            "{rule:?}: the walls they share"
        );
    }
}

#[test]
fn a_wall_one_member_drew_a_cell_off_in_one_region_is_re_aligned_there_and_drawn_once() {
    use smokenav_platform_map::{FREE, OCCUPIED, UNKNOWN};
    // A 8 m × 3 m hall (160 × 60 cells) with a partition at x = 40 for
    // y < 30. Member 1 drew the partition one cell east (x = 41) and every
    // other wall where the reference has it: no rigid transform lays both
    // on the reference. Member 2 never saw the partition (unknown there).
    let (w, h) = (160, 60);
    let hall = |partition_x: Option<usize>| {
        let mut g = OccupancyGrid::new(w, h, 0.05, [0.0, 0.0, 0.0]);
        for y in 0..h {
            for x in 0..w {
                let wall = x < 2 || y < 2 || x >= w - 2 || y >= h - 2;
                let part = partition_x == Some(x) && y < 30;
                g.cells[y * w + x] = if wall || part { OCCUPIED } else { FREE };
            }
        }
        g
    };
    let mut unseen = hall(None);
    for y in 2..30 {
        for x in 38..44 {
            unseen.cells[y * w + x] = UNKNOWN;
        }
    }
    let inputs = inputs_of(vec![hall(Some(40)), hall(Some(41)), unseen], |_| false);
    let fuse = |local_residual_m: f64| {
        let section = VoteSection {
            rule: VoteRule::Majority,
            local_residual_m,
            local_block_m: 1.5,
            ..VoteSection::default()
        };
        let f = fused_once(section, &inputs);
        (f.out.map.clone().unwrap(), f.out.local_blocks.clone())
    };
    // Rigid only: the three-way split (wall, free, unknown) is a wall under
    // the paper's rule on both columns, the partition drawn twice.
    let (rigid, blocks) = fuse(10.0);
    assert_eq!(blocks, [0, 0, 0]);
    for y in 2..30 {
        assert_eq!(
            [rigid.cells[y * w + 40], rigid.cells[y * w + 41]],
            [OCCUPIED; 2]
        );
    }
    // Re-aligned block by block (every member, whatever its residual): the
    // block holding member 1's partition moves a cell west, the wall is
    // drawn once, and the hall's walls elsewhere stay where they were.
    let (local, blocks) = fuse(0.0);
    assert!(
        blocks[1] >= 1,
        "member 1's partition block moved: {blocks:?}"
    );
    for y in 2..30 {
        assert_eq!(local.cells[y * w + 40], OCCUPIED, "y {y}");
        assert_eq!(local.cells[y * w + 41], FREE, "y {y}");
    }
    for x in 0..w {
        assert_eq!(local.cells[x], OCCUPIED, "the bottom wall at x {x}");
        assert_eq!(
            local.cells[(h - 1) * w + x],
            OCCUPIED,
            "the top wall at x {x}"
        );
    }
    // The default gate leaves member 1 alone: its rigid residual is ~0 (the
    // partition is under a fifth of its walls), so nothing is nudged.
    let (_, blocks) = fuse(VoteSection::default().local_residual_m);
    assert_eq!(blocks[1], 0);
}

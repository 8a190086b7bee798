//! The alignment on real maps: the simulator's R3.2 arena and a particle
//! filter's map of the dense-smoke trial (v2 fusion, `smokenav slam
//! --backend vote` member `rbpf`), stored as map_server PNGs.

use smokenav_algorithms_eval::map::{MapOptions, evaluate_maps};
use smokenav_platform_map::load_map_server;
use std::path::Path;

fn load(name: &str) -> smokenav_platform_map::OccupancyGrid {
    let path = Path::new(env!("CARGO_MANIFEST_DIR"))
        .join("tests/data")
        .join(name);
    load_map_server(&path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

#[test]
fn a_smoke_map_with_phantom_walls_is_not_turned_round() {
    // The arena is nearly symmetric under a half turn, and this map's
    // phantom walls (sonar arcs in the smoke) fit the turned-round arena
    // about as well as the walls it misses: the estimate's walls alone
    // picked −90° (k-NN 0.218 m); fitted both ways the map lies at +90°
    // (the robot started facing +y), 0.126 m.
    let truth = load("r32-truth.yaml");
    let est = load("r32-dense-smoke-rbpf.yaml");
    let r = evaluate_maps(&truth, &est, &MapOptions::default()).unwrap();
    assert!(
        (r.alignment.dtheta_deg - 90.0).abs() < 1.0,
        "{:?}",
        r.alignment
    );
    assert!(
        (r.alignment.dx_m - 1.03).abs() < 0.1 && (r.alignment.dy_m - 1.09).abs() < 0.1,
        "{:?}",
        r.alignment
    );
    assert!(r.knn_error_m < 0.15, "{}", r.knn_error_m);
}

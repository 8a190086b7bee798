//! Builds an occupancy grid from a CARMEN log taking its poses as exact
//! ("mapping with known poses"), e.g. to picture a reference such as the
//! GMapping-corrected CSAIL log next to what the filter made.
//!
//! `cargo run --release -p smokenav-algorithms-slam --example map_from_poses -- LOG[.gz not supported] OUT.png [resolution]`

use smokenav_algorithms_slam::carmen::{CarmenReader, Record};
use smokenav_algorithms_slam::grid::{BeamEnd, LogOddsModel, TiledGrid};
use std::io::BufReader;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let args: Vec<String> = std::env::args().collect();
    let (Some(log), Some(out)) = (args.get(1), args.get(2)) else {
        return Err("usage: map_from_poses LOG OUT.png [resolution_m]".into());
    };
    let resolution: f64 = args.get(3).map(|s| s.parse()).transpose()?.unwrap_or(0.05);
    let mut grid = TiledGrid::new(resolution);
    let model = LogOddsModel::new(0.9, 0.4, 4.0);
    let mut beams = Vec::new();
    let mut scans = 0;
    for rec in CarmenReader::new(BufReader::new(std::fs::File::open(log)?)) {
        let Ok(Record::Laser(l)) = rec else { continue };
        beams.clear();
        for (i, &r) in l.ranges.iter().enumerate() {
            if !(r.is_finite() && r > 0.0 && r < 80.0) {
                continue;
            }
            let (r, hit) = ((r as f64).min(16.0), r < 16.0);
            let a = l.laser_pose.theta + l.start_angle + i as f64 * l.angular_resolution;
            beams.push(BeamEnd {
                ex: l.laser_pose.x + r * a.cos(),
                ey: l.laser_pose.y + r * a.sin(),
                hit,
            });
        }
        grid.integrate(&l.laser_pose, &beams, &model);
        scans += 1;
    }
    let occ = grid.to_occupancy_grid();
    let out = std::path::Path::new(out);
    occ.save_png(out)?;
    let stem = out.file_stem().and_then(|s| s.to_str()).unwrap_or("map");
    smokenav_platform_map::save_map_server(
        &occ,
        out.parent().unwrap_or(std::path::Path::new(".")),
        stem,
    )?;
    println!("{scans} scans mapped into {}", out.display());
    Ok(())
}

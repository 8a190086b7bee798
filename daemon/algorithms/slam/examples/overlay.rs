//! Overlays an estimated map on a reference map after aligning the estimated
//! trajectory onto the reference trajectory (the best rigid 2D transform):
//! reference obstacles red, estimated blue, both black. Shows where two maps
//! of the same building disagree.
//!
//! `overlay REF.yaml REF_POSES EST.yaml EST_POSES OUT.png`

use smokenav_algorithms_eval::{TrajectoryOptions, evaluate_trajectories, load_trajectory};
use smokenav_algorithms_slam::Pose2;
use std::path::Path;

fn main() -> Result<(), Box<dyn std::error::Error>> {
    let a: Vec<String> = std::env::args().collect();
    if a.len() != 6 {
        return Err("usage: overlay REF.yaml REF_POSES EST.yaml EST_POSES OUT.png".into());
    }
    let reference = smokenav_platform_map::load_map_server(Path::new(&a[1]))?;
    let ref_poses = load_trajectory(Path::new(&a[2]))?;
    let est = smokenav_platform_map::load_map_server(Path::new(&a[3]))?;
    let est_poses = load_trajectory(Path::new(&a[4]))?;
    let ate = evaluate_trajectories(&ref_poses, &est_poses, &TrajectoryOptions::same_stamp())?;
    println!("{ate:?}");
    // Estimate → reference frame.
    let alignment = Pose2::new(
        ate.align_dx_m,
        ate.align_dy_m,
        ate.align_dtheta_deg.to_radians(),
    );
    let mut img = image::RgbImage::from_pixel(
        reference.width as u32,
        reference.height as u32,
        image::Rgb([230, 230, 230]),
    );
    let put = |img: &mut image::RgbImage, x: usize, y: usize, c: [u8; 3]| {
        let py = (reference.height - 1 - y) as u32;
        let p = img.get_pixel_mut(x as u32, py);
        p.0 = match (p.0, c) {
            ([200, 0, 0], [0, 0, 200]) | ([0, 0, 200], [200, 0, 0]) => [0, 0, 0],
            _ => c,
        };
    };
    for y in 0..reference.height {
        for x in 0..reference.width {
            if reference.get(x, y).is_some_and(|v| v >= 65) {
                put(&mut img, x, y, [200, 0, 0]);
            }
        }
    }
    for y in 0..est.height {
        for x in 0..est.width {
            if est.get(x, y).is_some_and(|v| v >= 65) {
                let (wx, wy) = est.cell_center(x, y);
                let r = alignment.transform_point(&nalgebra::Point2::new(wx, wy));
                if let Some((cx, cy)) = reference.world_to_cell(r.x, r.y) {
                    put(&mut img, cx, cy, [0, 0, 200]);
                }
            }
        }
    }
    img.save(&a[5])?;
    Ok(())
}

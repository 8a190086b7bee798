//! The demo's pictures: the maps side by side with the ground truth, where
//! their error lies, and smoke level vs laser spread vs sonar usage over time.

use super::Comparison;
use super::compare::{MethodResult, PhantomPlace, SeriesPoint};
use super::draw::{BLACK, Canvas, Color, GREY, LIGHT, WHITE, line_height, text_width};
use anyhow::Context;
use image::Rgb;
use smokenav_algorithms_eval::map::DEFAULT_OCCUPIED;
use smokenav_algorithms_eval::{Alignment, ErrorClass, ErrorPicture, error_picture};
use smokenav_platform_map::OccupancyGrid;
use smokenav_shared_types::FusionMethod;
use std::path::Path;

const TRUTH_PATH: Color = Rgb([0, 150, 60]);
const EST_PATH: Color = Rgb([215, 40, 40]);
const SMOKE: Color = Rgb([235, 120, 0]);
const V1: Color = Rgb([40, 90, 200]);
const V2: Color = Rgb([215, 40, 40]);
const SPREAD: Color = Rgb([120, 60, 170]);

fn title(m: FusionMethod) -> &'static str {
    match m {
        FusionMethod::LaserOnly => "Laser only",
        FusionMethod::V1 => "SmokeNav v1",
        FusionMethod::V2 => "SmokeNav v2",
    }
}

/// Estimate-map coordinates of a truth-frame point: the inverse of the
/// alignment `smokenav eval` found (which takes the estimate onto the truth).
fn to_estimate(a: &Alignment, x: f64, y: f64) -> (f64, f64) {
    let (s, c) = a.dtheta_deg.to_radians().sin_cos();
    let (x, y) = (x - a.dx_m, y - a.dy_m);
    (c * x + s * y, -s * x + c * y)
}

fn to_truth(a: &Alignment, x: f64, y: f64) -> (f64, f64) {
    let (s, c) = a.dtheta_deg.to_radians().sin_cos();
    (c * x - s * y + a.dx_m, s * x + c * y + a.dy_m)
}

/// map_server's look: unknown grey, free white, occupied black, in between shades.
fn cell_color(v: Option<i8>) -> Color {
    match v {
        None | Some(i8::MIN..=-1) => Rgb([205, 205, 205]),
        Some(v) => {
            let g = (255.0 - f64::from(v.min(100)) * 2.55).round() as u8;
            Rgb([g, g, g])
        }
    }
}

/// The world window every panel shows, and its scale.
struct View {
    x0: f64,
    y1: f64,
    px_per_m: f64,
    w: u32,
    h: u32,
}

impl View {
    fn px(&self, x: f64, y: f64) -> (i64, i64) {
        (
            ((x - self.x0) * self.px_per_m).floor() as i64,
            ((self.y1 - y) * self.px_per_m).floor() as i64,
        )
    }

    fn world(&self, px: u32, py: u32) -> (f64, f64) {
        (
            self.x0 + (f64::from(px) + 0.5) / self.px_per_m,
            self.y1 - (f64::from(py) + 0.5) / self.px_per_m,
        )
    }
}

fn render_map(view: &View, map: &OccupancyGrid, align: Option<&Alignment>) -> image::RgbImage {
    let mut img = image::RgbImage::new(view.w, view.h);
    for py in 0..view.h {
        for px in 0..view.w {
            let (wx, wy) = view.world(px, py);
            let (ex, ey) = match align {
                Some(a) => to_estimate(a, wx, wy),
                None => (wx, wy),
            };
            let v = map
                .world_to_cell(ex, ey)
                .and_then(|(cx, cy)| map.get(cx, cy));
            img.put_pixel(px, py, cell_color(v));
        }
    }
    img
}

fn draw_path(
    c: &mut Canvas,
    view: &View,
    ox: i64,
    oy: i64,
    pts: &[(f64, f64)],
    color: Color,
    thick: i64,
) {
    for w in pts.windows(2) {
        let (a, b) = (view.px(w[0].0, w[0].1), view.px(w[1].0, w[1].1));
        c.line(ox + a.0, oy + a.1, ox + b.0, oy + b.1, color, thick);
    }
}

/// Ground truth and the three maps side by side, in the truth's frame.
/// With the fuzzy back-end: per method, its occupancy map (Mo / (Mo + Ms),
/// what `slam/map` carries) above its combined confidence map (eq. 7, what
/// `slam/map_fuzzy` carries: darker = more confident obstacle, light grey =
/// unknown 0.3, white = sure free), both aligned to the truth like maps.png.
pub fn fuzzy_png(cmp: &Comparison, path: &Path) -> anyhow::Result<()> {
    let t = &cmp.truth_map;
    let margin = 0.5;
    let ww = t.width as f64 * t.resolution + 2.0 * margin;
    let wh = t.height as f64 * t.resolution + 2.0 * margin;
    let px_per_m = (560.0 / ww).min(440.0 / wh).max(5.0);
    let view = View {
        x0: t.origin[0] - margin,
        y1: t.origin[1] - margin + wh,
        px_per_m,
        w: (ww * px_per_m).ceil() as u32,
        h: (wh * px_per_m).ceil() as u32,
    };
    let (scale, gap) = (2, 16i64);
    let l = i64::from(line_height(scale));
    let head = l + 8;
    let panels = cmp.results.len() as i64;
    let width = gap + panels * (i64::from(view.w) + gap);
    let legend = [
        (
            PHANTOM_SMOKE,
            "confident cell > 0.6 m off walls, in the smoke",
        ),
        (PHANTOM_SMOKE_NEAR, "the same 0.3-0.6 m off a wall"),
        (PHANTOM_NEAR, "clear air, 0.3-0.6 m off a wall"),
        (
            PHANTOM_ELSEWHERE,
            "clear air, further (open space or outside)",
        ),
        (SMOKE, "edge of the smoke region"),
    ];
    let foot = legend.len() as i64 * (l + 4) + gap;
    let height = 2 * (head + i64::from(view.h)) + 2 * gap + foot;
    let mut c = Canvas::new(width as u32, height as u32, WHITE);
    let mut x = gap;
    for r in &cmp.results {
        let align = r.map_report.as_ref().ok().map(|m| m.alignment);
        let rows = [
            (r.map.as_ref(), format!("{}: occupancy", title(r.method))),
            (
                r.confidence_map.as_ref(),
                "fuzzy confidence (eq. 7)".to_string(),
            ),
        ];
        for (k, (map, label)) in rows.iter().enumerate() {
            let y = k as i64 * (head + i64::from(view.h) + gap);
            match map {
                Some(m) => c.paste(&render_map(&view, m, align.as_ref()), x, y + head),
                None => c.fill_rect(x, y + head, i64::from(view.w), i64::from(view.h), LIGHT),
            }
            if k == 1 {
                if let Some(region) = &cmp.smoke_region {
                    draw_region_edge(&mut c, &view, x, y + head, region);
                }
                for p in &r.fuzzy_phantoms {
                    let (px, py) = view.px(p.x, p.y);
                    c.dot(x + px, y + head + py, 2, phantom_color(p.place));
                }
            }
            c.text(x, y + 4, label, BLACK, scale);
            c.rect(
                x - 1,
                y + head - 1,
                i64::from(view.w) + 2,
                i64::from(view.h) + 2,
                GREY,
            );
        }
        x += i64::from(view.w) + gap;
    }
    let mut y = 2 * (head + i64::from(view.h)) + 2 * gap;
    for (color, text) in legend {
        c.dot(gap + 4, y + l / 2, 4, color);
        c.text(gap + 16, y, text, BLACK, scale);
        y += l + 4;
    }
    c.img
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

const PHANTOM_SMOKE: Color = Rgb([215, 40, 40]);
const PHANTOM_SMOKE_NEAR: Color = Rgb([200, 40, 200]);
const PHANTOM_NEAR: Color = Rgb([40, 90, 200]);
const PHANTOM_ELSEWHERE: Color = Rgb([0, 150, 60]);

fn phantom_color(p: PhantomPlace) -> Color {
    match p {
        PhantomPlace::Smoke => PHANTOM_SMOKE,
        PhantomPlace::SmokeNearWall => PHANTOM_SMOKE_NEAR,
        PhantomPlace::NearWall => PHANTOM_NEAR,
        PhantomPlace::OutsideArena | PhantomPlace::OpenSpace => PHANTOM_ELSEWHERE,
    }
}

/// The cells of the smoke region (truth frame) with a neighbour outside it.
fn draw_region_edge(c: &mut Canvas, view: &View, ox: i64, oy: i64, region: &OccupancyGrid) {
    let inside = |x: i64, y: i64| {
        x >= 0 && y >= 0 && region.get(x as usize, y as usize).is_some_and(|v| v > 0)
    };
    for y in 0..region.height as i64 {
        for x in 0..region.width as i64 {
            if !inside(x, y)
                || (inside(x - 1, y) && inside(x + 1, y) && inside(x, y - 1) && inside(x, y + 1))
            {
                continue;
            }
            let (wx, wy) = (
                region.origin[0] + (x as f64 + 0.5) * region.resolution,
                region.origin[1] + (y as f64 + 0.5) * region.resolution,
            );
            let (px, py) = view.px(wx, wy);
            c.dot(ox + px, oy + py, 1, SMOKE);
        }
    }
}

/// The truth map and half a metre around it, in about 560 × 440 pixels
/// (never under 5 pixels a metre).
fn truth_view(t: &OccupancyGrid) -> View {
    let margin = 0.5;
    let (wx0, wy0) = (t.origin[0] - margin, t.origin[1] - margin);
    let ww = t.width as f64 * t.resolution + 2.0 * margin;
    let wh = t.height as f64 * t.resolution + 2.0 * margin;
    let px_per_m = (560.0 / ww).min(440.0 / wh).max(5.0);
    View {
        x0: wx0,
        y1: wy0 + wh,
        px_per_m,
        w: (ww * px_per_m).ceil() as u32,
        h: (wh * px_per_m).ceil() as u32,
    }
}

pub fn maps_png(cmp: &Comparison, path: &Path) -> anyhow::Result<()> {
    let t = &cmp.truth_map;
    let view = truth_view(t);
    let px_per_m = view.px_per_m;
    let scale = 2;
    let gap = 16i64;
    let head = 3 * i64::from(line_height(scale)) + 8;
    let foot = 2 * i64::from(line_height(scale)) + 16;
    let panels = 1 + cmp.results.len() as i64;
    let width = gap + panels * (i64::from(view.w) + gap);
    let height = head + i64::from(view.h) + foot;
    let mut c = Canvas::new(width as u32, height as u32, WHITE);
    let truth_pts: Vec<(f64, f64)> = cmp
        .truth
        .samples()
        .iter()
        .map(|s| (s.pose.x, s.pose.y))
        .collect();

    let mut x = gap;
    // Ground truth, with the smoke sources.
    c.paste(&render_map(&view, t, None), x, head);
    for &(sx, sy, r) in &cmp.smoke_sources {
        let (cx, cy) = view.px(sx, sy);
        let rad = (r.max(0.4) * px_per_m) as i64;
        for k in 0..72 {
            let a0 = f64::from(k) * 5f64.to_radians();
            let a1 = a0 + 5f64.to_radians();
            if k % 2 == 0 {
                c.line(
                    x + cx + (rad as f64 * a0.cos()) as i64,
                    head + cy - (rad as f64 * a0.sin()) as i64,
                    x + cx + (rad as f64 * a1.cos()) as i64,
                    head + cy - (rad as f64 * a1.sin()) as i64,
                    SMOKE,
                    2,
                );
            }
        }
        c.dot(x + cx, head + cy, 4, SMOKE);
        c.text(x + cx - 40, head + cy + rad + 6, "smoke", SMOKE, scale);
    }
    draw_path(&mut c, &view, x, head, &truth_pts, TRUTH_PATH, 2);
    c.text(x, 8, "Ground truth", BLACK, scale);
    c.text(
        x,
        8 + i64::from(line_height(scale)),
        &cmp.scenario,
        GREY,
        scale,
    );
    c.rect(
        x - 1,
        head - 1,
        i64::from(view.w) + 2,
        i64::from(view.h) + 2,
        GREY,
    );
    x += i64::from(view.w) + gap;

    for r in &cmp.results {
        let align = r.map_report.as_ref().ok().map(|m| m.alignment);
        match &r.map {
            Some(m) => c.paste(&render_map(&view, m, align.as_ref()), x, head),
            None => c.fill_rect(x, head, i64::from(view.w), i64::from(view.h), LIGHT),
        }
        draw_path(&mut c, &view, x, head, &truth_pts, TRUTH_PATH, 1);
        if let Some(a) = &align {
            let est: Vec<(f64, f64)> = r
                .trajectory
                .iter()
                .map(|p| to_truth(a, p.pose.x, p.pose.y))
                .collect();
            draw_path(&mut c, &view, x, head, &est, EST_PATH, 2);
        }
        let l = i64::from(line_height(scale));
        c.text(x, 8, title(r.method), BLACK, scale);
        // The scores of the map shown (the median seed's).
        let err = match (&r.map_report, &r.trajectory_report) {
            (Ok(m), Ok(t)) => format!(
                "map error {:.3} m, ATE {:.3} m",
                m.knn_error_m, t.ate_m.rmse
            ),
            (Ok(m), Err(_)) => format!("map error {:.3} m", m.knn_error_m),
            _ => "not scored".into(),
        };
        c.text(x, 8 + l, &err, BLACK, scale);
        let seeds = match (cmp.seeds > 1, r.map_error_m()) {
            (true, Some(m)) => format!(", mean of {} seeds {m:.3} m", cmp.seeds),
            _ => String::new(),
        };
        c.text(
            x,
            8 + 2 * l,
            &format!("sonar usage {:.1}%{seeds}", r.sonar_usage * 100.0),
            GREY,
            scale,
        );
        c.rect(
            x - 1,
            head - 1,
            i64::from(view.w) + 2,
            i64::from(view.h) + 2,
            GREY,
        );
        x += i64::from(view.w) + gap;
    }

    // Legend and scale bar.
    let y = head + i64::from(view.h) + 12;
    let mut lx = gap;
    c.line(lx, y + 6, lx + 30, y + 6, TRUTH_PATH, 3);
    lx += 38;
    c.text(lx, y, "true path", BLACK, scale);
    lx += i64::from(text_width("true path", scale)) + 24;
    c.line(lx, y + 6, lx + 30, y + 6, EST_PATH, 3);
    lx += 38;
    c.text(lx, y, "SLAM path (aligned)", BLACK, scale);
    lx += i64::from(text_width("SLAM path (aligned)", scale)) + 24;
    let bar = px_per_m as i64;
    c.line(lx, y + 6, lx + bar, y + 6, BLACK, 3);
    c.line(lx, y, lx, y + 12, BLACK, 2);
    c.line(lx + bar, y, lx + bar, y + 12, BLACK, 2);
    c.text(lx + bar + 8, y, "1 m", BLACK, scale);
    lx += bar + 60;
    c.text(
        lx,
        y,
        "maps aligned to the truth by the k-NN best fit; black occupied, white free, grey unknown",
        GREY,
        scale,
    );
    c.img
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

fn render_errors(view: &View, pic: &ErrorPicture) -> image::RgbImage {
    let mut img = image::RgbImage::new(view.w, view.h);
    for py in 0..view.h {
        for px in 0..view.w {
            let (wx, wy) = view.world(px, py);
            img.put_pixel(px, py, Rgb(pic.at(wx, wy).rgb()));
        }
    }
    img
}

/// Where each method's map error lies, side by side in the truth's frame
/// (the picture `smokenav eval --error-image` draws), with the k-NN
/// error's split: walls on their place, misplaced, missing, phantom.
pub fn errors_png(cmp: &Comparison, path: &Path) -> anyhow::Result<()> {
    let t = &cmp.truth_map;
    let view = truth_view(t);
    let (w, h) = (i64::from(view.w), i64::from(view.h));
    let scale = 2;
    let l = i64::from(line_height(scale));
    let gap = 16i64;
    let head = 4 * l + 8;
    let foot = 2 * l + 16;
    let panels = cmp.results.len().max(1) as i64;
    let mut c = Canvas::new(
        (gap + panels * (w + gap)) as u32,
        (head + h + foot) as u32,
        WHITE,
    );
    let mut x = gap;
    for r in &cmp.results {
        let scored = match (&r.map, &r.map_report) {
            (Some(m), Ok(report)) => error_picture(t, m, &report.alignment, DEFAULT_OCCUPIED)
                .ok()
                .map(|pic| (pic, report)),
            _ => None,
        };
        c.text(x, 8, title(r.method), BLACK, scale);
        match &scored {
            Some((pic, report)) => {
                c.paste(&render_errors(&view, pic), x, head);
                let (to_map, to_truth) = (&report.truth_to_map_bands, &report.map_to_truth_bands);
                c.text(
                    x,
                    8 + l,
                    &format!("map error {:.3} m:", report.knn_error_m),
                    BLACK,
                    scale,
                );
                c.text(
                    x,
                    8 + 2 * l,
                    &format!(
                        "walls {:.3}, misplaced {:.3},",
                        to_map.on_wall.knn_share_m + to_truth.on_wall.knn_share_m,
                        to_map.misplaced.knn_share_m + to_truth.misplaced.knn_share_m
                    ),
                    GREY,
                    scale,
                );
                c.text(
                    x,
                    8 + 3 * l,
                    &format!(
                        "missing {:.3}, phantom {:.3} m",
                        to_map.far.knn_share_m, to_truth.far.knn_share_m
                    ),
                    GREY,
                    scale,
                );
            }
            None => {
                c.fill_rect(x, head, w, h, LIGHT);
                c.text(x, 8 + l, "not scored", GREY, scale);
            }
        }
        c.rect(x - 1, head - 1, w + 2, h + 2, GREY);
        x += w + gap;
    }
    // Legend.
    let y = head + h + 12;
    let mut lx = gap;
    for (class, label) in [
        (ErrorClass::EstimateOnWall, "wall on its place"),
        (ErrorClass::EstimateMisplaced, "misplaced"),
        (ErrorClass::Phantom, "phantom"),
        (ErrorClass::TruthMisplaced, "true wall drawn off it"),
        (ErrorClass::Missing, "missing"),
    ] {
        c.fill_rect(lx, y, 14, 14, Rgb(class.rgb()));
        lx += 20;
        c.text(lx, y, label, BLACK, scale);
        lx += i64::from(text_width(label, scale)) + 24;
    }
    c.img
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

/// A "nice" tick step for a span: 1, 2 or 5 × 10^k giving 4–10 ticks.
fn tick_step(span: f64) -> f64 {
    if !(span.is_finite() && span > 0.0) {
        return 1.0;
    }
    let raw = span / 6.0;
    let mag = 10f64.powf(raw.log10().floor());
    let n = raw / mag;
    let f = if n < 1.5 {
        1.0
    } else if n < 3.5 {
        2.0
    } else if n < 7.5 {
        5.0
    } else {
        10.0
    };
    f * mag
}

fn fmt_tick(v: f64, step: f64) -> String {
    if step >= 1.0 {
        format!("{v:.0}")
    } else if step >= 0.1 {
        format!("{v:.1}")
    } else {
        format!("{v:.2}")
    }
}

/// A named, coloured line of (t, y) points.
type Series<'a> = (&'a str, Color, Vec<(f64, f64)>);

/// One panel of the time plot.
struct Panel<'a> {
    label: &'a str,
    y_min: f64,
    y_max: f64,
    /// (name, color, points (t, y)).
    series: Vec<Series<'a>>,
    /// Horizontal reference lines: (value, label).
    refs: Vec<(f64, String)>,
}

fn moving_average(points: &[(f64, f64)], window_s: f64) -> Vec<(f64, f64)> {
    let mut out = Vec::with_capacity(points.len());
    let (mut lo, mut sum) = (0usize, 0.0);
    for (i, &(t, v)) in points.iter().enumerate() {
        sum += v;
        while points[lo].0 < t - window_s {
            sum -= points[lo].1;
            lo += 1;
        }
        out.push((t, sum / (i + 1 - lo) as f64));
    }
    out
}

/// Smoke level vs laser spread vs sonar usage over time (the v2 run's fused scans).
pub fn smoke_png(cmp: &Comparison, path: &Path) -> anyhow::Result<()> {
    let find = |m| cmp.results.iter().find(|r: &&MethodResult| r.method == m);
    let v2 = find(FusionMethod::V2);
    let t0 = cmp
        .truth
        .samples()
        .first()
        .map(|s| s.t_ns)
        .or_else(|| v2.and_then(|r| r.series.first().map(|p| p.stamp_ns)))
        .unwrap_or(0);
    let ts = |p: &SeriesPoint| (p.stamp_ns as f64 - t0 as f64) * 1e-9;
    let series = |m, f: fn(&SeriesPoint) -> f64| -> Vec<(f64, f64)> {
        find(m).map_or(Vec::new(), |r| {
            r.series.iter().map(|p| (ts(p), f(p))).collect()
        })
    };
    let level = series(FusionMethod::V2, |p| f64::from(p.smoke_level));
    let spread = series(FusionMethod::V2, |p| f64::from(p.laser_spread));
    let use_v1 = moving_average(
        &series(FusionMethod::V1, |p| f64::from(p.sonar_usage) * 100.0),
        1.0,
    );
    let use_v2 = moving_average(
        &series(FusionMethod::V2, |p| f64::from(p.sonar_usage) * 100.0),
        1.0,
    );
    let t_end = [&level, &use_v1]
        .iter()
        .filter_map(|s| s.last().map(|p| p.0))
        .fold(cmp.sim_s, f64::max)
        .max(1.0);
    let max_of = |s: &[(f64, f64)]| {
        s.iter()
            .map(|p| p.1)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::max)
    };
    let min_of = |s: &[(f64, f64)]| {
        s.iter()
            .map(|p| p.1)
            .filter(|v| v.is_finite())
            .fold(0.0, f64::min)
    };
    let [smin, sup, sdown] = cmp.smoke_thresholds;
    let mut panels = vec![
        Panel {
            label: "smoke level (mV below clean air)",
            y_min: min_of(&level).min(0.0),
            y_max: (max_of(&level) * 1.1).max(sdown * 1.15),
            series: vec![("smoke level", SMOKE, level)],
            refs: vec![
                (smin, format!("v1 SMOKE_MIN {smin:.0}")),
                (sup, format!("v1 SMOKE_MAX_UP {sup:.0}")),
                (sdown, format!("v1 SMOKE_MAX_DOWN {sdown:.0}")),
            ],
        },
        Panel {
            label: "laser spread (std. dev. of ranges, m)",
            y_min: 0.0,
            y_max: (max_of(&spread) * 1.1).max(0.1),
            series: vec![("laser spread", SPREAD, spread)],
            refs: Vec::new(),
        },
    ];
    if !cmp.laser_damage.is_empty() {
        panels.push(Panel {
            label: "laser beams changed by the smoke (%, vs the smoke-free twin; ground truth)",
            y_min: 0.0,
            y_max: 100.0,
            series: vec![("changed", GREY, cmp.laser_damage.clone())],
            refs: Vec::new(),
        });
    }
    panels.push(Panel {
        label: "sonar usage (% of sections, 1 s mean)",
        y_min: 0.0,
        y_max: 100.0,
        series: vec![("v1", V1, use_v1), ("v2", V2, use_v2)],
        refs: Vec::new(),
    });
    let n = panels.len() as i64;

    let scale = 2u32;
    let lh = i64::from(line_height(scale));
    let (w, ph) = (1400i64, 230i64);
    let (left, right, top, gap) = (110i64, 30i64, 60i64, 70i64);
    let h = top + n * ph + (n - 1) * gap + 70;
    let mut c = Canvas::new(w as u32, h as u32, WHITE);
    c.text(
        left,
        14,
        &format!(
            "{}: smoke level vs laser spread vs sonar usage",
            cmp.scenario
        ),
        BLACK,
        scale,
    );
    let pw = w - left - right;
    let xs = |t: f64| left + (t / t_end * pw as f64).round() as i64;
    let xstep = tick_step(t_end);
    for (i, p) in panels.iter().enumerate() {
        let y0 = top + i as i64 * (ph + gap);
        let span = (p.y_max - p.y_min).max(1e-9);
        let ys = |v: f64| y0 + ph - ((v - p.y_min) / span * ph as f64).round() as i64;
        c.rect(left, y0, pw, ph, BLACK);
        // Grid and ticks.
        let ystep = tick_step(span);
        let mut v = (p.y_min / ystep).ceil() * ystep;
        while v <= p.y_max + 1e-9 {
            let y = ys(v);
            c.dashed(left + 1, y, left + pw - 2, y, LIGHT, 1, 4);
            c.line(left - 6, y, left, y, BLACK, 1);
            let s = fmt_tick(v, ystep);
            c.text(
                left - 10 - i64::from(text_width(&s, scale)),
                y - lh / 3,
                &s,
                BLACK,
                scale,
            );
            v += ystep;
        }
        let mut t = 0.0;
        while t <= t_end + 1e-9 {
            let x = xs(t);
            c.dashed(x, y0 + 1, x, y0 + ph - 2, LIGHT, 1, 4);
            c.line(x, y0 + ph, x, y0 + ph + 6, BLACK, 1);
            let s = fmt_tick(t, xstep);
            c.text(
                x - i64::from(text_width(&s, scale)) / 2,
                y0 + ph + 10,
                &s,
                BLACK,
                scale,
            );
            t += xstep;
        }
        // Reference lines, their labels side by side so close values stay readable.
        let mut label_right = left + pw - 8;
        for (value, label) in &p.refs {
            let y = ys(*value);
            c.dashed(left + 1, y, left + pw - 2, y, GREY, 1, 8);
            let w = i64::from(text_width(label, scale));
            c.text(label_right - w, y - lh + 4, label, GREY, scale);
            label_right -= w + 24;
        }
        // Earlier series wider, so a later one drawn over it leaves it visible.
        let n = p.series.len() as i64;
        for (k, (_, color, pts)) in p.series.iter().enumerate() {
            let thick = 2 + 3 * (n - 1 - k as i64);
            for seg in pts.windows(2) {
                let (a, b) = (seg[0], seg[1]);
                if a.1.is_finite() && b.1.is_finite() {
                    c.line(xs(a.0), ys(a.1), xs(b.0), ys(b.1), *color, thick);
                }
            }
        }
        c.text(left + 8, y0 + 8, p.label, BLACK, scale);
        // Legend for panels with several series.
        if p.series.len() > 1 {
            let mut lx = left + 8 + i64::from(text_width(p.label, scale)) + 30;
            for (name, color, _) in &p.series {
                c.line(lx, y0 + 14, lx + 30, y0 + 14, *color, 3);
                c.text(lx + 36, y0 + 8, name, BLACK, scale);
                lx += 36 + i64::from(text_width(name, scale)) + 24;
            }
        }
    }
    let label = "time since start (s)";
    c.text(
        left + pw / 2 - i64::from(text_width(label, scale)) / 2,
        top + n * ph + (n - 1) * gap + 30,
        label,
        BLACK,
        scale,
    );
    c.img
        .save(path)
        .with_context(|| format!("cannot write {}", path.display()))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn ticks_are_round_numbers() {
        assert_eq!(tick_step(180.0), 20.0);
        assert_eq!(tick_step(1.0), 0.2);
        assert_eq!(tick_step(300.0), 50.0);
        assert_eq!(tick_step(0.0), 1.0);
    }

    #[test]
    fn alignment_round_trips() {
        let a = Alignment {
            dx_m: 1.0,
            dy_m: -2.0,
            dtheta_deg: 90.0,
        };
        let (x, y) = to_truth(&a, 1.0, 0.0);
        assert!((x - 1.0).abs() < 1e-12 && (y - -1.0).abs() < 1e-12);
        let (ex, ey) = to_estimate(&a, x, y);
        assert!((ex - 1.0).abs() < 1e-12 && ey.abs() < 1e-12);
    }

    #[test]
    fn moving_average_spans_the_window() {
        let pts = [(0.0, 0.0), (0.5, 10.0), (1.0, 20.0), (2.0, 40.0)];
        let m = moving_average(&pts, 1.0);
        assert_eq!(m[2].1, 10.0);
        assert_eq!(m[3].1, 30.0);
    }
}

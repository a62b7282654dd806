//! Pictures for people: the bird's-eye map (regions, obstacles, curriculum region,
//! validation points, first task, fixed start, goal, trajectories), enlarged
//! first-person views, and episode GIFs with the view beside the map.
//!
//! Invariant: the map is drawn from the same region map the rewards use, so what
//! a person sees is what the agent is rewarded for. North is up.

use std::path::Path;

use image::{Rgb, RgbImage, Rgba, RgbaImage};

use crate::appearance::Paving;
use crate::error::{Result, SimError};
use crate::region_map::RegionMap;
use crate::scene::{Footprint, ObstacleKind, Pose, RegionKind, Scene};

/// Colour of each region kind on the map.
pub fn region_color(kind: RegionKind) -> [u8; 3] {
    match kind {
        RegionKind::Road => [70, 70, 78],
        RegionKind::Sidewalk => [190, 186, 176],
        RegionKind::GoalSidewalk => [170, 200, 225],
        RegionKind::Zebra => [235, 235, 235],
        RegionKind::Goal => [70, 190, 90],
    }
}

/// 3×5 bitmaps of the digits 0–9 (one row per 3-bit number, top first).
const DIGITS: [[u8; 5]; 10] = [
    [7, 5, 5, 5, 7],
    [2, 6, 2, 2, 7],
    [7, 1, 7, 4, 7],
    [7, 1, 7, 1, 7],
    [5, 5, 7, 1, 1],
    [7, 4, 7, 1, 7],
    [7, 4, 7, 5, 7],
    [7, 1, 1, 1, 1],
    [7, 5, 7, 5, 7],
    [7, 5, 7, 1, 7],
];

/// A bird's-eye canvas with the scene drawn on it and a world→pixel transform.
#[derive(Clone)]
pub struct MapCanvas {
    /// The picture.
    pub image: RgbImage,
    /// Pixels per metre.
    pub scale: f32,
    x0: f32,
    y1: f32,
}

impl MapCanvas {
    /// Pixel coordinates of a world point (may lie outside the image).
    pub fn to_px(&self, x: f32, y: f32) -> (f32, f32) {
        ((x - self.x0) * self.scale, (self.y1 - y) * self.scale)
    }

    fn put(&mut self, px: i64, py: i64, c: [u8; 3]) {
        if px >= 0 && py >= 0 && (px as u32) < self.image.width() && (py as u32) < self.image.height() {
            self.image.put_pixel(px as u32, py as u32, Rgb(c));
        }
    }

    /// Filled disc of radius `r` pixels at a world point.
    pub fn disc(&mut self, x: f32, y: f32, r: f32, c: [u8; 3]) {
        let (cx, cy) = self.to_px(x, y);
        let ri = r.ceil() as i64 + 1;
        for dy in -ri..=ri {
            for dx in -ri..=ri {
                let (px, py) = (cx.floor() as i64 + dx, cy.floor() as i64 + dy);
                let (fx, fy) = (px as f32 + 0.5 - cx, py as f32 + 0.5 - cy);
                if fx * fx + fy * fy <= r * r {
                    self.put(px, py, c);
                }
            }
        }
    }

    /// Line between two world points, `w` pixels wide.
    pub fn line(&mut self, a: (f32, f32), b: (f32, f32), w: f32, c: [u8; 3]) {
        let (ax, ay) = self.to_px(a.0, a.1);
        let (bx, by) = self.to_px(b.0, b.1);
        let n = ((bx - ax).abs().max((by - ay).abs()) * 2.0).ceil().max(1.0) as usize;
        for k in 0..=n {
            let t = k as f32 / n as f32;
            let (px, py) = (ax + (bx - ax) * t, ay + (by - ay) * t);
            let r = (w * 0.5).max(0.5);
            let ri = r.ceil() as i64;
            for dy in -ri..=ri {
                for dx in -ri..=ri {
                    if ((dx * dx + dy * dy) as f32) <= r * r {
                        self.put(px as i64 + dx, py as i64 + dy, c);
                    }
                }
            }
        }
    }

    /// A polyline through world points.
    pub fn polyline(&mut self, pts: &[(f32, f32)], w: f32, c: [u8; 3]) {
        for p in pts.windows(2) {
            self.line(p[0], p[1], w, c);
        }
    }

    /// A number written with the built-in 3×5 digit font, `s` pixels per font pixel,
    /// centred at a world point, on a white box.
    pub fn label(&mut self, x: f32, y: f32, n: u32, s: i64, c: [u8; 3]) {
        let text = n.to_string();
        let (cx, cy) = self.to_px(x, y);
        let w = text.len() as i64 * 4 * s - s;
        let (left, top) = (cx as i64 - w / 2, cy as i64 - 5 * s / 2);
        for py in top - s..top + 6 * s {
            for px in left - s..left + w + s {
                self.put(px, py, [255, 255, 255]);
            }
        }
        for (k, ch) in text.bytes().enumerate() {
            let glyph = DIGITS[(ch - b'0') as usize];
            for (row, bits) in glyph.iter().enumerate() {
                for col in 0..3 {
                    if bits >> (2 - col) & 1 == 1 {
                        for dy in 0..s {
                            for dx in 0..s {
                                self.put(left + (k as i64 * 4 + col) * s + dx, top + row as i64 * s + dy, c);
                            }
                        }
                    }
                }
            }
        }
    }

    /// An arrow showing a pose (position and heading), `len` metres long.
    pub fn pose_arrow(&mut self, pose: Pose, len: f32, c: [u8; 3]) {
        let tip = (pose.x + len * pose.yaw.cos(), pose.y + len * pose.yaw.sin());
        self.line((pose.x, pose.y), tip, 2.0, c);
        for side in [-1.0f32, 1.0] {
            let a = pose.yaw + std::f32::consts::PI + side * 0.5;
            self.line(tip, (tip.0 + 0.4 * len * a.cos(), tip.1 + 0.4 * len * a.sin()), 2.0, c);
        }
        self.disc(pose.x, pose.y, 2.5, c);
    }
}

/// Draw the scene from above: regions, hatched curriculum region, obstacles,
/// validation points (red 0–7 inside, blue 8–13 outside), the first task (black
/// star) and the fixed start (black triangle).
pub fn draw_map(scene: &Scene, map: &RegionMap, px_per_m: f32) -> MapCanvas {
    let w = (scene.extent.width() * px_per_m).round() as u32;
    let h = (scene.extent.height() * px_per_m).round() as u32;
    let mut canvas =
        MapCanvas { image: RgbImage::new(w, h), scale: px_per_m, x0: scene.extent.min[0], y1: scene.extent.max[1] };
    for py in 0..h {
        for px in 0..w {
            let x = scene.extent.min[0] + (px as f32 + 0.5) / px_per_m;
            let y = scene.extent.max[1] - (py as f32 + 0.5) / px_per_m;
            let kind = map.kind_at(x, y);
            let mut c = region_color(kind);
            if kind == RegionKind::Zebra && !scene.on_zebra_stripe(x, y) {
                c = region_color(RegionKind::Road);
            }
            if matches!(kind, RegionKind::Sidewalk | RegionKind::GoalSidewalk) {
                // Paved areas in their own tone, relative to the default paving.
                if let Some(p) = scene.paving.iter().rev().find(|p| p.bounds.contains(x, y) && p.area.contains(x, y)) {
                    let k = (p.tone / Paving::DEFAULT.tone).clamp(0.4, 1.4);
                    c = c.map(|v| (v as f32 * k).min(255.0) as u8);
                }
            }
            if scene.in_curriculum_region(x, y) && ((px + py) % 9) < 2 {
                c = [200, 60, 160];
            }
            canvas.image.put_pixel(px, py, Rgb(c));
        }
    }
    for o in &scene.obstacles {
        let color = match o.kind {
            ObstacleKind::Building => {
                let g = (o.shade * 160.0) as u8 + 40;
                [g, g.saturating_sub(15), g.saturating_sub(30)]
            }
            ObstacleKind::Pole => [10, 10, 10],
            ObstacleKind::Bench => [120, 80, 40],
            ObstacleKind::Tree => [40, 130, 40],
            ObstacleKind::Wall => [40, 40, 40],
        };
        match o.footprint {
            Footprint::Box(r) => {
                let (ax, ay) = canvas.to_px(r.min[0], r.max[1]);
                let (bx, by) = canvas.to_px(r.max[0], r.min[1]);
                for py in ay.floor() as i64..by.ceil() as i64 {
                    for px in ax.floor() as i64..bx.ceil() as i64 {
                        canvas.put(px, py, color);
                    }
                }
            }
            Footprint::Cylinder { center, radius } => {
                canvas.disc(center[0], center[1], (radius.max(o.crown_radius) * px_per_m).max(2.0), color);
            }
        }
    }
    // Overhead details (awnings, signs, canopies): outlined, the ground shows through.
    for o in &scene.overhead {
        let (a, b) = (o.rect.min, o.rect.max);
        let corners = [(a[0], a[1]), (b[0], a[1]), (b[0], b[1]), (a[0], b[1]), (a[0], a[1])];
        for k in 0..4 {
            canvas.line(corners[k], corners[k + 1], 1.5, [90, 60, 120]);
        }
    }
    let s = (px_per_m / 3.0).round().max(1.0) as i64;
    for p in scene.validation_points() {
        let c = if p.id < 8 { [210, 30, 30] } else { [30, 60, 210] };
        canvas.disc(p.x, p.y, 2.0 * s as f32 + 1.0, c);
        canvas.label(p.x, p.y + 1.6 * 3.0 / px_per_m * s as f32 + 0.6, p.id, s, c);
    }
    let ft = scene.first_task();
    for k in 0..5 {
        let a = ft.yaw + k as f32 * std::f32::consts::TAU / 5.0;
        let b = a + std::f32::consts::TAU * 2.0 / 5.0;
        let r = 0.9;
        canvas.line((ft.x + r * a.cos(), ft.y + r * a.sin()), (ft.x + r * b.cos(), ft.y + r * b.sin()), 2.0, [0, 0, 0]);
    }
    let fs = scene.fixed_start();
    let tri: Vec<(f32, f32)> = (0..4)
        .map(|k| {
            let a = std::f32::consts::FRAC_PI_2 + k as f32 * std::f32::consts::TAU / 3.0;
            (fs.x + 0.9 * a.cos(), fs.y + 0.9 * a.sin())
        })
        .collect();
    canvas.polyline(&tri, 2.0, [0, 0, 0]);
    canvas
}

/// An episode film: each frame is the first-person view enlarged ×4 beside the
/// map with the trajectory so far (red) and the camera's heading (orange) — the
/// GIFs of `pednav-sim record` and `pednav-eval --gif`.
pub struct Film {
    base: MapCanvas,
    view_size: u32,
    frames: Vec<RgbImage>,
}

impl Film {
    /// Enlargement of the first-person view.
    const VIEW_SCALE: u32 = 4;
    /// Map scale in pixels per metre.
    const MAP_PX_PER_M: f32 = 4.0;
    /// Display time of one frame.
    const FRAME_MS: u32 = 100;

    /// An empty film of `world`, whose views are `world.config.image_size` square.
    pub fn new(world: &crate::SimWorld) -> Film {
        Film {
            base: draw_map(&world.scene, &world.map, Self::MAP_PX_PER_M),
            view_size: world.config.image_size,
            frames: Vec::new(),
        }
    }

    /// Add a frame: `view` (greyscale, `image_size`² bytes; `None` draws a black
    /// view, e.g. in state mode), the trajectory `trail` so far and the camera's
    /// pose (`yaw` = the camera's heading).
    pub fn add(&mut self, view: Option<&[u8]>, trail: &[(f32, f32)], camera: Pose) {
        let black;
        let view = match view {
            Some(v) => v,
            None => {
                black = vec![0u8; (self.view_size * self.view_size) as usize];
                &black
            }
        };
        let mut canvas = self.base.clone();
        canvas.polyline(trail, 2.0, [220, 40, 40]);
        canvas.pose_arrow(camera, 2.0, [250, 140, 0]);
        self.frames.push(side_by_side(&enlarge_gray(view, self.view_size, Self::VIEW_SCALE), &canvas.image));
    }

    /// Frames so far.
    pub fn len(&self) -> usize {
        self.frames.len()
    }

    /// Whether no frame was added.
    pub fn is_empty(&self) -> bool {
        self.frames.is_empty()
    }

    /// Write the film as a looping GIF.
    pub fn save(&self, path: &Path) -> Result<()> {
        save_gif(&self.frames, Self::FRAME_MS, path)
    }
}

/// Enlarge a greyscale frame by an integer factor (nearest neighbour) into RGB.
pub fn enlarge_gray(frame: &[u8], size: u32, factor: u32) -> RgbImage {
    let out = size * factor;
    RgbImage::from_fn(out, out, |x, y| {
        let g = frame[((y / factor) * size + x / factor) as usize];
        Rgb([g, g, g])
    })
}

/// Place `left` and `right` side by side on a dark background (tops aligned).
pub fn side_by_side(left: &RgbImage, right: &RgbImage) -> RgbImage {
    let gap = 8;
    let w = left.width() + gap + right.width();
    let h = left.height().max(right.height());
    let mut out = RgbImage::from_pixel(w, h, Rgb([25, 25, 25]));
    image::imageops::replace(&mut out, left, 0, 0);
    image::imageops::replace(&mut out, right, (left.width() + gap) as i64, 0);
    out
}

/// Save an image as PNG, creating parent directories.
pub fn save_png(img: &RgbImage, path: &Path) -> Result<()> {
    ensure_parent(path)?;
    img.save(path).map_err(|e| SimError::Output { path: path.to_path_buf(), message: e.to_string() })
}

/// Save a greyscale frame as an 8-bit greyscale PNG.
pub fn save_gray_png(frame: &[u8], size: u32, path: &Path) -> Result<()> {
    ensure_parent(path)?;
    let img = image::GrayImage::from_raw(size, size, frame.to_vec()).expect("frame has size² bytes");
    img.save(path).map_err(|e| SimError::Output { path: path.to_path_buf(), message: e.to_string() })
}

fn ensure_parent(path: &Path) -> Result<()> {
    if let Some(dir) = path.parent().filter(|d| !d.as_os_str().is_empty()) {
        std::fs::create_dir_all(dir)
            .map_err(|e| SimError::Output { path: dir.to_path_buf(), message: e.to_string() })?;
    }
    Ok(())
}

/// Write frames as an animated GIF (`delay_ms` per frame, looping).
pub fn save_gif(frames: &[RgbImage], delay_ms: u32, path: &Path) -> Result<()> {
    ensure_parent(path)?;
    let err = |e: &dyn std::fmt::Display| SimError::Output { path: path.to_path_buf(), message: e.to_string() };
    let file = std::fs::File::create(path).map_err(|e| err(&e))?;
    let mut enc = image::codecs::gif::GifEncoder::new_with_speed(std::io::BufWriter::new(file), 10);
    enc.set_repeat(image::codecs::gif::Repeat::Infinite).map_err(|e| err(&e))?;
    for f in frames {
        let rgba = RgbaImage::from_fn(f.width(), f.height(), |x, y| {
            let p = f.get_pixel(x, y).0;
            Rgba([p[0], p[1], p[2], 255])
        });
        let frame = image::Frame::from_parts(rgba, 0, 0, image::Delay::from_numer_denom_ms(delay_ms, 1));
        enc.encode_frame(frame).map_err(|e| err(&e))?;
    }
    Ok(())
}

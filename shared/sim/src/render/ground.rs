//! The ground texture: the region map turned into greyscale paving, one texel per
//! map cell, plus a full CPU-built mip chain.
//!
//! Invariant: texel `(i, j)` shows the region of map cell `(i, j)` — the picture
//! and the reward map cannot disagree. Looks (chosen so that every region is
//! distinct in an 84×84 greyscale view):
//! - road: dark asphalt (≈0.25) with fine seeded grain; painted markings ≈0.85;
//! - zebra: 0.5 m white stripes (≈0.9) alternating with asphalt along the walking axis;
//! - sidewalks (both kinds alike — a region's kind never shows, its place does):
//!   the scene's paving where it has one (slabs, bricks, cobbles or concrete
//!   panels in their own tone, [`crate::appearance`]), else light slabs (≈0.62)
//!   with darker joints every 0.6 m;
//! - kerb: a 0.2 m band of kerb stone (the paving's, default bright ≈0.85) where
//!   sidewalk meets road or zebra;
//! - goal: a 1 m checkerboard of white and dark tiles (a paved plaza), bold enough
//!   to be seen from the zebra crossing through the 135° lens at 84 px.

use crate::appearance::{Paving, PavingLook, PavingStyle};
use crate::region_map::RegionMap;
use crate::scene::{RegionKind, Scene};

/// A greyscale texture with its mip chain, tightly packed level after level.
pub struct GroundTexture {
    /// Width of level 0.
    pub width: u32,
    /// Height of level 0.
    pub height: u32,
    /// Number of mip levels.
    pub mip_levels: u32,
    /// All levels, level 0 first, row 0 at the scene's south edge.
    pub data: Vec<u8>,
}

/// Deterministic value in [−1, 1] of an integer pair (a hash, no RNG state).
fn hash(i: u32, j: u32) -> f32 {
    let mut h = i.wrapping_mul(0x9E37_79B1) ^ j.wrapping_mul(0x85EB_CA77);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    (h & 0xFFFF) as f32 / 32767.5 - 1.0
}

/// Per-texel grain in [−1, 1].
fn grain(i: usize, j: usize) -> f32 {
    hash(i as u32, j as u32)
}

/// Per-stone tone variation in [−1, 1] of the stone with (possibly negative) indices `(a, b)`.
fn stone(a: f32, b: f32) -> f32 {
    hash((a as i32) as u32 ^ 0x5bd1_e995, (b as i32) as u32)
}

/// Width of a joint between paving stones, metres (one texel of the default 0.05 m cell).
const JOINT: f32 = 0.05;

/// Grey level of paving `p` at world point `(x, y)`; `g` is the texel's grain.
fn paving_grey(p: PavingLook, x: f32, y: f32, g: f32) -> f32 {
    let s = p.size;
    match p.style {
        PavingStyle::Slabs | PavingStyle::Concrete => {
            if x.rem_euclid(s) < JOINT || y.rem_euclid(s) < JOINT {
                p.joint
            } else {
                let variation = if p.style == PavingStyle::Concrete { 0.015 } else { 0.02 };
                p.tone + variation * g
            }
        }
        PavingStyle::Bricks => {
            // Running bond: rows `s / 2` wide along x, every other row shifted by half a brick.
            let w = 0.5 * s;
            let row = (y / w).floor();
            let xs = x + if (row as i64).rem_euclid(2) == 1 { 0.5 * s } else { 0.0 };
            if xs.rem_euclid(s) < JOINT || y.rem_euclid(w) < JOINT {
                p.joint
            } else {
                p.tone + 0.05 * stone((xs / s).floor(), row) + 0.015 * g
            }
        }
        PavingStyle::Lawn => p.tone + 0.07 * stone((x / s).floor(), (y / s).floor()) + 0.03 * g,
        PavingStyle::Cobbles => {
            // Square setts in rows, each row shifted by its own amount; wide joints.
            let row = (y / s).floor();
            let xs = x + s * 0.5 * (stone(row, 7.0) + 1.0);
            if xs.rem_euclid(s) < 1.5 * JOINT || y.rem_euclid(s) < 1.5 * JOINT {
                p.joint
            } else {
                p.tone + 0.08 * stone((xs / s).floor(), row) + 0.02 * g
            }
        }
    }
}

/// The paving at a point: the last paved area containing it, else the default slabs.
fn paving_at(pavings: &[Paving], x: f32, y: f32) -> PavingLook {
    pavings
        .iter()
        .rev()
        .find(|p| p.bounds.contains(x, y) && p.area.contains(x, y))
        .map_or(Paving::DEFAULT, Paving::look)
}

fn to_u8(v: f32) -> u8 {
    (v.clamp(0.0, 1.0) * 255.0).round() as u8
}

/// Bake level 0 of the ground texture from the region map.
pub fn bake_level0(scene: &Scene, map: &RegionMap) -> Vec<u8> {
    let (nx, ny, c) = (map.nx, map.ny, map.cell);
    let kerb_cells = (0.2 / c).round().max(1.0) as isize;
    let is_carriageway = |i: isize, j: isize| -> bool {
        if i < 0 || j < 0 || i >= nx as isize || j >= ny as isize {
            return false;
        }
        matches!(RegionKind::from_label(map.label(i as usize, j as usize)), RegionKind::Road | RegionKind::Zebra)
    };
    let mut out = vec![0u8; nx * ny];
    for j in 0..ny {
        for i in 0..nx {
            let (x, y) = map.cell_center(i, j);
            let kind = RegionKind::from_label(map.label(i, j));
            let g = grain(i, j);
            let v = match kind {
                RegionKind::Road => 0.25 + 0.03 * g,
                RegionKind::Zebra => {
                    if scene.on_zebra_stripe(x, y) {
                        0.9 + 0.02 * g
                    } else {
                        0.25 + 0.03 * g
                    }
                }
                RegionKind::Sidewalk | RegionKind::GoalSidewalk => {
                    let (ii, jj) = (i as isize, j as isize);
                    let near_road = (1..=kerb_cells).any(|k| {
                        is_carriageway(ii + k, jj)
                            || is_carriageway(ii - k, jj)
                            || is_carriageway(ii, jj + k)
                            || is_carriageway(ii, jj - k)
                    });
                    let paving = paving_at(&scene.paving, x, y);
                    if near_road { paving.kerb + 0.02 * g } else { paving_grey(paving, x, y, g) }
                }
                RegionKind::Goal => {
                    let checker = (x.floor() as i64 + y.floor() as i64).rem_euclid(2) == 0;
                    if checker { 0.95 } else { 0.32 }
                }
            };
            out[j * nx + i] = to_u8(v);
        }
    }
    for m in &scene.spec.markings {
        paint_marking(&mut out, map, m);
    }
    out
}

fn paint_marking(out: &mut [u8], map: &RegionMap, m: &crate::scene::Marking) {
    let (dx, dy) = (m.to[0] - m.from[0], m.to[1] - m.from[1]);
    let len = (dx * dx + dy * dy).sqrt();
    if len <= 0.0 {
        return;
    }
    let (ux, uy) = (dx / len, dy / len);
    let half = m.width * 0.5;
    let pad = half + map.cell;
    let (i0, j0) = map.cell_of(m.from[0].min(m.to[0]) - pad, m.from[1].min(m.to[1]) - pad);
    let (i1, j1) = map.cell_of(m.from[0].max(m.to[0]) + pad, m.from[1].max(m.to[1]) + pad);
    for j in j0..=j1 {
        for i in i0..=i1 {
            let (x, y) = map.cell_center(i, j);
            let (rx, ry) = (x - m.from[0], y - m.from[1]);
            let along = rx * ux + ry * uy;
            let across = (-rx * uy + ry * ux).abs();
            if along < 0.0 || along > len || across > half {
                continue;
            }
            if m.dash > 0.0 && along.rem_euclid(m.dash + m.gap) > m.dash {
                continue;
            }
            out[j * map.nx + i] = to_u8(0.85);
        }
    }
}

/// Box-filter a level to the next (odd sizes clamp at the edge).
fn downsample(src: &[u8], w: usize, h: usize) -> (Vec<u8>, usize, usize) {
    let (nw, nh) = ((w / 2).max(1), (h / 2).max(1));
    let mut dst = vec![0u8; nw * nh];
    for j in 0..nh {
        for i in 0..nw {
            let (a, b) = ((2 * i).min(w - 1), (2 * i + 1).min(w - 1));
            let (c, d) = ((2 * j).min(h - 1), (2 * j + 1).min(h - 1));
            let s = src[c * w + a] as u32 + src[c * w + b] as u32 + src[d * w + a] as u32 + src[d * w + b] as u32;
            dst[j * nw + i] = ((s + 2) / 4) as u8;
        }
    }
    (dst, nw, nh)
}

/// Bake the ground texture and its mip chain.
pub fn bake(scene: &Scene, map: &RegionMap) -> GroundTexture {
    let level0 = bake_level0(scene, map);
    let (mut w, mut h) = (map.nx, map.ny);
    let mut data = level0.clone();
    let mut level = level0;
    let mut mip_levels = 1;
    while w > 1 || h > 1 {
        let (next, nw, nh) = downsample(&level, w, h);
        data.extend_from_slice(&next);
        level = next;
        w = nw;
        h = nh;
        mip_levels += 1;
    }
    GroundTexture { width: map.nx as u32, height: map.ny as u32, mip_levels, data }
}

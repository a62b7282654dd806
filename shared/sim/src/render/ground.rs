//! The ground texture: the region map turned into greyscale paving, one texel per
//! map cell, plus a full CPU-built mip chain.
//!
//! Invariant: texel `(i, j)` shows the region of map cell `(i, j)` — the picture
//! and the reward map cannot disagree. Looks (chosen so that every region is
//! distinct in an 84×84 greyscale view):
//! - road: dark asphalt (≈0.25) with fine seeded grain; painted markings ≈0.85;
//! - zebra: 0.5 m white stripes (≈0.9) alternating with asphalt along the walking axis;
//! - sidewalks (both kinds look alike — the goal side is told apart by the layout):
//!   light paving (≈0.62) with darker joints every 0.6 m;
//! - kerb: a 0.2 m band of bright kerb stone (≈0.85) where sidewalk meets road or zebra;
//! - goal: a 1 m checkerboard of white and dark tiles (a paved plaza), bold enough
//!   to be seen from the zebra crossing through the 135° lens at 84 px.

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

/// Deterministic per-texel grain in [−1, 1] (an integer hash, no RNG state).
fn grain(i: usize, j: usize) -> f32 {
    let mut h = (i as u32).wrapping_mul(0x9E37_79B1) ^ (j as u32).wrapping_mul(0x85EB_CA77);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2C1B_3C6D);
    h ^= h >> 12;
    (h & 0xFFFF) as f32 / 32767.5 - 1.0
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
                    if near_road {
                        0.85 + 0.02 * g
                    } else {
                        let joint = x.rem_euclid(0.6) < 0.05 || y.rem_euclid(0.6) < 0.05;
                        if joint { 0.48 } else { 0.62 + 0.02 * g }
                    }
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

//! Shapes on the ground plane as scene files write them: axis-aligned rectangles,
//! simple polygons, and an [`Area`] that is either — with the checks every region,
//! paved area, curriculum area and obstacle of a scene goes through.
//!
//! Invariant: a [`Rect`] or [`Polygon`] returned by [`resolve_rect`] or
//! [`Area::resolve`] is finite and non-degenerate (a polygon also simple: no two of
//! its edges cross), and every refusal names the scene file and the field.

use serde::{Deserialize, Serialize};

use crate::error::{Result, SimError};

/// Tallest wall or obstacle a scene may have, in metres (a 300-storey tower; a
/// larger value is a typo that would only stretch the mesh and its depth range).
pub const MAX_HEIGHT: f32 = 1000.0;

/// A refusal of a scene's field: where the scene came from, which field, and why.
pub(crate) fn invalid(origin: &str, field: &str, message: String) -> SimError {
    SimError::SceneInvalid { origin: origin.to_string(), field: field.to_string(), message }
}

/// Axis along which a pedestrian walks over a zebra crossing; the stripes
/// alternate along it (each stripe is long across this axis).
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Axis {
    /// Walking direction along x.
    X,
    /// Walking direction along y.
    Y,
}

/// An axis-aligned rectangle `[x_min, y_min, x_max, y_max]` in metres.
#[derive(Debug, Clone, Copy, PartialEq, Serialize, Deserialize)]
pub struct Rect {
    /// Lower-left corner.
    pub min: [f32; 2],
    /// Upper-right corner.
    pub max: [f32; 2],
}

impl Rect {
    /// Does the rectangle contain the point (closed on all sides)?
    pub fn contains(&self, x: f32, y: f32) -> bool {
        x >= self.min[0] && x <= self.max[0] && y >= self.min[1] && y <= self.max[1]
    }
    /// Width along x.
    pub fn width(&self) -> f32 {
        self.max[0] - self.min[0]
    }
    /// Height along y.
    pub fn height(&self) -> f32 {
        self.max[1] - self.min[1]
    }
    /// Distance from a point to the rectangle (0 inside or on it).
    pub fn distance(&self, x: f32, y: f32) -> f32 {
        let dx = (self.min[0] - x).max(x - self.max[0]).max(0.0);
        let dy = (self.min[1] - y).max(y - self.max[1]).max(0.0);
        dx.hypot(dy)
    }
    /// Do the two rectangles share at least a point?
    pub fn intersects(&self, other: &Rect) -> bool {
        self.min[0] <= other.max[0]
            && other.min[0] <= self.max[0]
            && self.min[1] <= other.max[1]
            && other.min[1] <= self.max[1]
    }
    /// Does `self` lie inside `other` (boundaries included)?
    pub fn within(&self, other: &Rect) -> bool {
        other.contains(self.min[0], self.min[1]) && other.contains(self.max[0], self.max[1])
    }
    fn polygon(&self) -> Vec<[f32; 2]> {
        vec![
            [self.min[0], self.min[1]],
            [self.max[0], self.min[1]],
            [self.max[0], self.max[1]],
            [self.min[0], self.max[1]],
        ]
    }
}

/// A simple polygon (any winding, not self-intersecting) in metres.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(transparent)]
pub struct Polygon(pub Vec<[f32; 2]>);

impl Polygon {
    /// Even-odd point-in-polygon test.
    pub fn contains(&self, x: f32, y: f32) -> bool {
        let v = &self.0;
        let mut inside = false;
        let mut j = v.len() - 1;
        for i in 0..v.len() {
            let (xi, yi) = (v[i][0], v[i][1]);
            let (xj, yj) = (v[j][0], v[j][1]);
            if (yi > y) != (yj > y) && x < (xj - xi) * (y - yi) / (yj - yi) + xi {
                inside = !inside;
            }
            j = i;
        }
        inside
    }

    /// Bounding box of the polygon.
    pub fn bounds(&self) -> Rect {
        let mut r = Rect { min: [f32::INFINITY; 2], max: [f32::NEG_INFINITY; 2] };
        for p in &self.0 {
            r.min[0] = r.min[0].min(p[0]);
            r.min[1] = r.min[1].min(p[1]);
            r.max[0] = r.max[0].max(p[0]);
            r.max[1] = r.max[1].max(p[1]);
        }
        r
    }

    /// Area (shoelace formula), positive for either winding.
    pub fn area(&self) -> f32 {
        let v = &self.0;
        let mut a = 0.0;
        for i in 0..v.len() {
            let j = (i + 1) % v.len();
            a += v[i][0] * v[j][1] - v[j][0] * v[i][1];
        }
        (a * 0.5).abs()
    }

    /// The first pair of edges `(i, j)` that cross, if any (edge `i` runs from vertex
    /// `i` to vertex `i + 1`). Edges sharing a vertex are not compared; two edges
    /// cross when each one's end points lie strictly on opposite sides of the other.
    pub fn crossing_edges(&self) -> Option<(usize, usize)> {
        let v = &self.0;
        let n = v.len();
        let point = |k: usize| [f64::from(v[k % n][0]), f64::from(v[k % n][1])];
        // −1, 0 or 1: which side of the line a→b the point c lies on (0: on it, so
        // touching, collinear and zero-length edges never count as crossing).
        let side = |a: [f64; 2], b: [f64; 2], c: [f64; 2]| {
            let cross = (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]);
            f64::from(i8::from(cross > 0.0) - i8::from(cross < 0.0))
        };
        for i in 0..n {
            // j > i + 1 and not the edge that closes the loop back onto vertex i.
            for j in i + 2..n {
                if i == 0 && j == n - 1 {
                    continue;
                }
                let (a, b, c, d) = (point(i), point(i + 1), point(j), point(j + 1));
                if side(a, b, c) * side(a, b, d) < 0.0 && side(c, d, a) * side(c, d, b) < 0.0 {
                    return Some((i, j));
                }
            }
        }
        None
    }
}

/// A shape on the ground plane given either as `rect = [x0, y0, x1, y1]` or as
/// `polygon = [[x, y], ...]` in the scene file.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(deny_unknown_fields)]
pub struct Area {
    /// Axis-aligned rectangle `[x_min, y_min, x_max, y_max]`.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub rect: Option<[f32; 4]>,
    /// Polygon vertices.
    #[serde(default, skip_serializing_if = "Option::is_none")]
    pub polygon: Option<Vec<[f32; 2]>>,
}

impl Area {
    pub(crate) fn resolve(&self, field: &str, origin: &str) -> Result<Polygon> {
        match (&self.rect, &self.polygon) {
            (Some(r), None) => Ok(Polygon(resolve_rect(r, &format!("{field}.rect"), origin)?.polygon())),
            (None, Some(p)) => {
                let field = format!("{field}.polygon");
                if p.len() < 3 {
                    return Err(invalid(origin, &field, format!("needs at least 3 vertices, got {}", p.len())));
                }
                if let Some(k) = p.iter().position(|q| !(q[0].is_finite() && q[1].is_finite())) {
                    return Err(invalid(origin, &field, format!("vertex {k} {:?} is not finite", p[k])));
                }
                let poly = Polygon(p.clone());
                let b = poly.bounds();
                if !(b.width().is_finite() && b.height().is_finite()) {
                    return Err(invalid(origin, &field, "is wider than a 32-bit float can measure".into()));
                }
                let area = poly.area();
                if area.is_nan() || area <= 1e-6 {
                    return Err(invalid(origin, &field, "has zero area".into()));
                }
                if let Some((i, j)) = poly.crossing_edges() {
                    return Err(invalid(
                        origin,
                        &field,
                        format!("edges {i} and {j} cross: give the vertices in order around a simple polygon"),
                    ));
                }
                Ok(poly)
            }
            _ => Err(invalid(origin, field, "give exactly one of `rect` or `polygon`".into())),
        }
    }
}

/// A `[x_min, y_min, x_max, y_max]` rectangle from a scene file: finite, non-empty.
pub(crate) fn resolve_rect(r: &[f32; 4], field: &str, origin: &str) -> Result<Rect> {
    if !r.iter().all(|v| v.is_finite()) {
        return Err(invalid(origin, field, format!("{r:?} is not finite")));
    }
    let rect = Rect { min: [r[0], r[1]], max: [r[2], r[3]] };
    if !(rect.width() > 0.0 && rect.height() > 0.0) {
        return Err(invalid(origin, field, format!("{r:?} must satisfy x_min < x_max and y_min < y_max")));
    }
    if !(rect.width().is_finite() && rect.height().is_finite()) {
        return Err(invalid(origin, field, format!("{r:?} is wider than a 32-bit float can measure")));
    }
    Ok(rect)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn polygon_contains_matches_rect() {
        let p = Polygon(Rect { min: [0.0, 0.0], max: [2.0, 1.0] }.polygon());
        assert!(p.contains(1.0, 0.5));
        assert!(!p.contains(2.5, 0.5));
        assert!(!p.contains(1.0, -0.1));
        assert!((p.area() - 2.0).abs() < 1e-6);
    }

    #[test]
    fn crossing_edges_finds_a_bow_tie_only() {
        let bow_tie = Polygon(vec![[0.0, 0.0], [4.0, 2.0], [4.0, 0.0], [0.0, 4.0]]);
        assert_eq!(bow_tie.crossing_edges(), Some((0, 2)));
        // Simple polygons, convex and not, with collinear and touching-free edges.
        for p in [
            vec![[0.0, 0.0], [4.0, 0.0], [4.0, 4.0], [0.0, 4.0]],
            vec![[0.0, 0.0], [4.0, 0.0], [2.0, 1.0], [4.0, 4.0], [0.0, 4.0]],
            vec![[0.0, 0.0], [1.0, 0.0], [2.0, 0.0], [2.0, 1.0]],
            vec![[0.0, 0.0], [1.0, 0.0], [0.0, 1.0]],
            // Clockwise, the first vertex repeated at the end (a zero-length edge).
            vec![[0.0, 0.0], [0.0, 4.0], [4.0, 4.0], [4.0, 0.0], [0.0, 0.0]],
        ] {
            assert_eq!(Polygon(p.clone()).crossing_edges(), None, "{p:?}");
        }
    }
}

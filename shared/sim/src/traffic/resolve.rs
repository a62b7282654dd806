//! Checking a scene's `[traffic]` section: [`Traffic::resolve`] turns a
//! [`TrafficSpec`] into a [`Traffic`] or refuses it naming the field — lanes on the
//! road, the signal plan through the conflict monitor, walkers' network on the
//! sidewalks, every number in range.
//!
//! Invariant: nothing downstream re-checks what this module accepted (see the
//! parent module's invariant).

use super::spec::{
    DriverSpec, LaneSpec, LevelsSpec, PhaseSpec, SignalSpec, TrafficRewards, VehicleKindSpec, WalkerSpec,
};
use super::{
    Head, HeadKind, Lane, MIN_WALK_S, MUTCD_WALKING_SPEED, SignalPlan, Traffic, TrafficSpec, VehicleKind,
    WalkerNetwork, Zebra, signal,
};
use crate::config::{check_dont_walk_entry, check_level};
use crate::error::{Result, SimError};
use crate::geometry::{Axis, Polygon, Rect, invalid};
use crate::region_kind::RegionKind;

fn finite2(p: [f32; 2]) -> bool {
    p[0].is_finite() && p[1].is_finite()
}

/// Do segments a–b and c–d cross (properly or touching)? Returns the crossing point.
fn segments_cross(a: [f32; 2], b: [f32; 2], c: [f32; 2], d: [f32; 2]) -> Option<[f32; 2]> {
    let r = [b[0] - a[0], b[1] - a[1]];
    let s = [d[0] - c[0], d[1] - c[1]];
    let den = r[0] * s[1] - r[1] * s[0];
    if den.abs() < 1e-9 {
        return None;
    }
    let q = [c[0] - a[0], c[1] - a[1]];
    let t = (q[0] * s[1] - q[1] * s[0]) / den;
    let u = (q[0] * r[1] - q[1] * r[0]) / den;
    ((0.0..=1.0).contains(&t) && (0.0..=1.0).contains(&u)).then(|| [a[0] + t * r[0], a[1] + t * r[1]])
}

/// The traffic rewards' ranges: `Err((field, message))` for the first out of range.
fn check_rewards(r: &TrafficRewards) -> std::result::Result<(), (&'static str, String)> {
    if !(r.vehicle_hit.is_finite() && r.vehicle_hit <= 0.0) {
        return Err(("rewards.vehicle_hit", format!("{} must be finite and ≤ 0", r.vehicle_hit)));
    }
    check_dont_walk_entry(r.dont_walk_entry).map_err(|m| ("rewards.dont_walk_entry", m))
}

/// What the checks read: the scene's regions (kind, outline, walking axis, in paint
/// order), its extent, and the origin every error names.
struct Context<'a> {
    regions: &'a [(RegionKind, &'a Polygon, Option<Axis>)],
    extent: &'a Rect,
    origin: &'a str,
}

impl Context<'_> {
    /// The error for field `traffic.{field}`.
    fn bad(&self, field: &str, message: String) -> SimError {
        invalid(self.origin, &format!("traffic.{field}"), message)
    }

    /// The kind of the topmost region at (x, y): road where no region is.
    fn region_at(&self, x: f32, y: f32) -> RegionKind {
        self.regions.iter().rev().find(|r| r.1.contains(x, y)).map(|r| r.0).unwrap_or(RegionKind::Road)
    }

    /// Checks that zebra `z` (named at `field`) is one of the scene's zebras.
    fn check_zebra(&self, field: &str, z: usize, zebras: &[Zebra]) -> Result<()> {
        if z < zebras.len() {
            Ok(())
        } else {
            Err(self.bad(
                field,
                format!(
                    "zebra {z} does not exist: the scene has {} zebra regions (0–{})",
                    zebras.len(),
                    zebras.len().saturating_sub(1)
                ),
            ))
        }
    }
}

impl Traffic {
    /// Validate a traffic section against its scene's regions (kind, outline and a
    /// zebra's walking axis, in paint order) and extent; the scene checks the heads'
    /// poles and the walkers' clearance of its obstacles. Every error names the field
    /// (`traffic.lanes[2].stop_line`, `traffic.signal.phases[0]`, …).
    pub fn resolve(
        spec: &TrafficSpec,
        regions: &[(RegionKind, &Polygon, Option<Axis>)],
        extent: &Rect,
        origin: &str,
    ) -> Result<Traffic> {
        let cx = Context { regions, extent, origin };
        let zebras = resolve_zebras(&cx);
        let (roads, mut lanes) = resolve_lanes(&cx, &spec.lanes, &zebras)?;
        add_conflict_points(&mut lanes);
        let plan = resolve_signal(&cx, &spec.signal, &roads, &lanes, &zebras)?;
        let kinds = resolve_vehicle_kinds(&cx, &spec.vehicle_kinds)?;
        check_driver(&cx, &spec.driver)?;
        let walkers = resolve_walkers(&cx, &spec.walkers, &zebras)?;
        check_levels(&cx, &spec.levels)?;
        let heads = resolve_heads(&cx, spec, &roads, &zebras)?;
        check_rewards(&spec.rewards).map_err(|(field, message)| cx.bad(field, message))?;
        if !(1..=16).contains(&spec.substeps) {
            return Err(cx.bad("substeps", format!("{} must lie in [1, 16]", spec.substeps)));
        }
        if !(spec.warmup_s >= 0.0 && spec.warmup_s <= 1800.0) {
            return Err(cx.bad("warmup_s", format!("{} must lie in [0, 1800] seconds", spec.warmup_s)));
        }
        Ok(Traffic {
            roads,
            lanes,
            zebras,
            plan,
            kinds,
            driver: spec.driver.clone(),
            walkers,
            levels: spec.levels.clone(),
            heads,
            extra_poles: spec.extra_poles.clone(),
            vehicle_hit: spec.rewards.vehicle_hit,
            dont_walk_entry: spec.rewards.dont_walk_entry,
            substeps: spec.substeps,
            warmup_s: spec.warmup_s,
        })
    }
}

/// Zebras: the scene's zebra regions in file order, with their walking axis and length.
fn resolve_zebras(cx: &Context) -> Vec<Zebra> {
    cx.regions
        .iter()
        .filter(|r| r.0 == RegionKind::Zebra)
        .map(|&(_, polygon, walk_axis)| {
            let bounds = polygon.bounds();
            let axis = walk_axis.unwrap_or(Axis::Y);
            let length = match axis {
                Axis::X => bounds.width(),
                Axis::Y => bounds.height(),
            };
            Zebra { polygon: polygon.clone(), bounds, walk_axis: axis, length }
        })
        .collect()
}

/// Lanes (ends, length, stop line, on the road, zebras crossed) and the roads, in order of first lane.
fn resolve_lanes(cx: &Context, specs: &[LaneSpec], zebras: &[Zebra]) -> Result<(Vec<String>, Vec<Lane>)> {
    if specs.is_empty() {
        return Err(cx.bad("lanes", "at least one lane is required".into()));
    }
    let mut roads: Vec<String> = Vec::new();
    let mut lanes = Vec::with_capacity(specs.len());
    for (i, l) in specs.iter().enumerate() {
        let field = format!("lanes[{i}]");
        if l.road.trim().is_empty() {
            return Err(
                cx.bad(&format!("{field}.road"), "must name the road (the signal plan gives green by road)".into())
            );
        }
        for (name, p) in [("from", l.from), ("to", l.to), ("stop_line", l.stop_line)] {
            if !finite2(p) {
                return Err(cx.bad(&format!("{field}.{name}"), format!("{p:?} is not finite")));
            }
        }
        let (dx, dy) = (l.to[0] - l.from[0], l.to[1] - l.from[1]);
        let length = dx.hypot(dy);
        if !(length >= 20.0 && length <= 5000.0) {
            return Err(cx.bad(&format!("{field}.to"), format!("the lane is {length} m long: it must be 20–5000 m")));
        }
        let road = match roads.iter().position(|r| *r == l.road) {
            Some(k) => k,
            None => {
                roads.push(l.road.clone());
                roads.len() - 1
            }
        };
        let mut lane = Lane {
            road,
            origin: l.from,
            dir: [dx / length, dy / length],
            length,
            stop_s: 0.0,
            zebras: vec![],
            conflicts: vec![],
            box_exit: None,
        };
        let (s, off) = lane.local(l.stop_line);
        if !(off.abs() <= 0.5 && s > 0.0 && s < length) {
            return Err(cx.bad(
                &format!("{field}.stop_line"),
                format!(
                    "{:?} must lie on the lane between `from` and `to` (it is {off:.2} m off the centreline, at {s:.1} m of {length:.1})",
                    l.stop_line
                ),
            ));
        }
        lane.stop_s = s;
        check_lane_on_road(cx, &field, &lane, l.stop_line)?;
        lane.zebras = zebra_intervals(&lane, zebras);
        lanes.push(lane);
    }
    Ok((roads, lanes))
}

/// Checks a lane is on the road wherever it is inside the world, with room for a vehicle, and its stop line on road.
fn check_lane_on_road(cx: &Context, field: &str, lane: &Lane, stop_line: [f32; 2]) -> Result<()> {
    let mut k = 0.0;
    while k <= lane.length {
        let c = lane.point(k);
        for side in [-1.0f32, 0.0, 1.0] {
            let p = [c[0] - lane.dir[1] * side, c[1] + lane.dir[0] * side];
            if cx.extent.contains(p[0], p[1]) {
                let kind = cx.region_at(p[0], p[1]);
                if !matches!(kind, RegionKind::Road | RegionKind::Zebra) {
                    return Err(cx.bad(
                        field,
                        format!(
                            "the lane leaves the road at ({:.1}, {:.1}): that is {kind:?} (a lane and 1 m either side of it must be road or zebra)",
                            p[0], p[1]
                        ),
                    ));
                }
            }
        }
        k += 0.5;
    }
    let stop_kind = cx.region_at(stop_line[0], stop_line[1]);
    if cx.extent.contains(stop_line[0], stop_line[1]) && stop_kind != RegionKind::Road {
        return Err(cx.bad(
            &format!("{field}.stop_line"),
            format!("stands on {stop_kind:?}: a stop line is on the road, before the zebra"),
        ));
    }
    Ok(())
}

/// The zebras a lane crosses, as `(zebra, enter, leave)` along it, in order along the lane.
fn zebra_intervals(lane: &Lane, zebras: &[Zebra]) -> Vec<(usize, f32, f32)> {
    let mut intervals = Vec::new();
    for (z, zebra) in zebras.iter().enumerate() {
        let mut enter = None;
        let mut leave = 0.0;
        let mut k = 0.0;
        while k <= lane.length {
            let p = lane.point(k);
            if zebra.contains(p[0], p[1]) {
                enter.get_or_insert(k);
                leave = k;
            }
            k += 0.05;
        }
        if let Some(e) = enter {
            intervals.push((z, e, leave));
        }
    }
    intervals.sort_by(|a, b| a.1.total_cmp(&b.1));
    intervals
}

/// Conflict points between lanes of different roads, and where each lane leaves the box.
fn add_conflict_points(lanes: &mut [Lane]) {
    for i in 0..lanes.len() {
        for j in 0..lanes.len() {
            if lanes[i].road == lanes[j].road {
                continue;
            }
            let (a, b) = (&lanes[i], &lanes[j]);
            if let Some(c) = segments_cross(a.origin, a.point(a.length), b.origin, b.point(b.length)) {
                let (si, sj) = (a.local(c).0, b.local(c).0);
                lanes[i].conflicts.push((j, si, sj));
            }
        }
        lanes[i].box_exit = lanes[i].conflicts.iter().map(|c| c.1 + 2.0).reduce(f32::max);
    }
}

/// The signal plan: its intervals, each phase, every road green in some phase, and the cycle's length.
fn resolve_signal(
    cx: &Context,
    sig: &SignalSpec,
    roads: &[String],
    lanes: &[Lane],
    zebras: &[Zebra],
) -> Result<SignalPlan> {
    if !(sig.amber_s >= 3.0 && sig.amber_s <= 6.0) {
        return Err(cx.bad("signal.amber_s", format!("{} must lie in [3, 6] seconds (ITE practice)", sig.amber_s)));
    }
    if !(sig.all_red_s >= 0.0 && sig.all_red_s <= 6.0) {
        return Err(cx.bad("signal.all_red_s", format!("{} must lie in [0, 6] seconds", sig.all_red_s)));
    }
    if sig.phases.is_empty() {
        return Err(cx.bad("signal.phases", "at least one phase is required".into()));
    }
    let mut phases = Vec::with_capacity(sig.phases.len());
    for (k, p) in sig.phases.iter().enumerate() {
        phases.push(resolve_phase(cx, &format!("signal.phases[{k}]"), p, roads, lanes, zebras)?);
    }
    for (r, name) in roads.iter().enumerate() {
        if !phases.iter().any(|p| p.green.contains(&r)) {
            return Err(
                cx.bad("signal.phases", format!("road {name:?} never gets green: its vehicles would queue for ever"))
            );
        }
    }
    let plan = SignalPlan::new(phases, sig.amber_s as f64, sig.all_red_s as f64);
    if !(plan.cycle_s >= 30.0 && plan.cycle_s <= 240.0) {
        return Err(
            cx.bad("signal.phases", format!("the cycle is {} s: it must lie in [30, 240] seconds", plan.cycle_s))
        );
    }
    Ok(plan)
}

/// One phase (at `field`): its green time, green roads through the conflict monitor, and its walks.
fn resolve_phase(
    cx: &Context,
    field: &str,
    p: &PhaseSpec,
    roads: &[String],
    lanes: &[Lane],
    zebras: &[Zebra],
) -> Result<signal::Phase> {
    if !(p.green_s >= 5.0 && p.green_s <= 120.0) {
        return Err(cx.bad(&format!("{field}.green_s"), format!("{} must lie in [5, 120] seconds", p.green_s)));
    }
    let mut green = Vec::new();
    for name in &p.green {
        let r = roads.iter().position(|r| r == name).ok_or_else(|| {
            cx.bad(&format!("{field}.green"), format!("no lane is on road {name:?}; the roads are {roads:?}"))
        })?;
        green.push(r);
    }
    check_conflict_monitor(cx, field, &green, roads, lanes)?;
    check_walks(cx, field, p, &green, roads, lanes, zebras)?;
    Ok(signal::Phase {
        green,
        walk: p.walk.clone(),
        green_s: p.green_s as f64,
        walk_s: p.walk_s as f64,
        clearance_s: p.clearance_s as f64,
    })
}

/// The conflict monitor: refuses a phase giving two roads whose lanes cross green at once.
fn check_conflict_monitor(cx: &Context, field: &str, green: &[usize], roads: &[String], lanes: &[Lane]) -> Result<()> {
    for (x, &ra) in green.iter().enumerate() {
        for &rb in &green[x + 1..] {
            for la in lanes.iter().filter(|l| l.road == ra) {
                for lb in lanes.iter().filter(|l| l.road == rb) {
                    if let Some(c) = segments_cross(la.origin, la.point(la.length), lb.origin, lb.point(lb.length)) {
                        return Err(cx.bad(
                            field,
                            format!(
                                "gives conflicting movements green at once: roads {:?} and {:?} cross at ({:.1}, {:.1}) (a conflict monitor would go to flashing red)",
                                roads[ra], roads[rb], c[0], c[1]
                            ),
                        ));
                    }
                }
            }
        }
    }
    Ok(())
}

/// A phase's walks: existing zebras beside the parallel green only, WALK and clearance long enough, within green.
fn check_walks(
    cx: &Context,
    field: &str,
    p: &PhaseSpec,
    green: &[usize],
    roads: &[String],
    lanes: &[Lane],
    zebras: &[Zebra],
) -> Result<()> {
    for &z in &p.walk {
        cx.check_zebra(&format!("{field}.walk"), z, zebras)?;
        // A walk beside a crossing vehicle green (or its amber).
        if let Some(l) = lanes.iter().find(|l| green.contains(&l.road) && l.zebras.iter().any(|(zz, _, _)| *zz == z)) {
            return Err(cx.bad(
                field,
                format!(
                    "lets zebra {z} walk while road {:?}, whose lane crosses it, has green: a walk runs only beside the parallel green",
                    roads[l.road]
                ),
            ));
        }
        let need = zebras[z].length / MUTCD_WALKING_SPEED;
        if !(p.walk_s >= MIN_WALK_S) {
            return Err(cx.bad(
                &format!("{field}.walk_s"),
                format!("{} is shorter than the {MIN_WALK_S} s minimum walk (MUTCD 4E.06)", p.walk_s),
            ));
        }
        if !(p.clearance_s >= need) {
            return Err(cx.bad(
                &format!("{field}.clearance_s"),
                format!(
                    "{} s is shorter than zebra {z}'s {:.1} m at {MUTCD_WALKING_SPEED} m/s ({need:.2} s): a walker who starts at the end of WALK could not finish",
                    p.clearance_s, zebras[z].length
                ),
            ));
        }
    }
    if !p.walk.is_empty() && !(p.walk_s + p.clearance_s <= p.green_s) {
        return Err(cx.bad(
            field,
            format!("walk_s + clearance_s = {} must end within green_s = {}", p.walk_s + p.clearance_s, p.green_s),
        ));
    }
    if p.walk.is_empty() && (p.walk_s != 0.0 || p.clearance_s != 0.0) {
        return Err(cx.bad(field, "gives walk_s / clearance_s but no zebra walks (`walk = [...]`)".into()));
    }
    Ok(())
}

/// Vehicle kinds: at least one, each size and share in range, shares made cumulative.
fn resolve_vehicle_kinds(cx: &Context, specs: &[VehicleKindSpec]) -> Result<Vec<VehicleKind>> {
    if specs.is_empty() {
        return Err(cx.bad("vehicle_kinds", "at least one kind is required".into()));
    }
    let total: f32 = specs.iter().map(|k| k.share.max(0.0)).sum();
    let mut kinds = Vec::with_capacity(specs.len());
    let mut acc = 0.0;
    for (i, k) in specs.iter().enumerate() {
        let field = format!("vehicle_kinds[{i}]");
        for (name, v, lo, hi) in [
            ("share", k.share, 0.0, 1e6),
            ("length", k.length, 2.0, 20.0),
            ("width", k.width, 1.0, 3.0),
            ("height", k.height, 1.0, 4.5),
        ] {
            if !(v >= lo && v <= hi) || (name == "share" && v <= 0.0) {
                return Err(cx.bad(
                    &format!("{field}.{name}"),
                    format!("{v} must lie in {}{lo}, {hi}]", if name == "share" { "(" } else { "[" }),
                ));
            }
        }
        acc += k.share / total;
        kinds.push(VehicleKind {
            name: k.name.clone(),
            cumulative_share: if i + 1 == specs.len() { 1.0 } else { acc },
            length: k.length,
            width: k.width,
            height: k.height,
            style: k.style,
        });
    }
    Ok(kinds)
}

/// Drivers: every parameter in range, and hard braking at least the comfortable.
fn check_driver(cx: &Context, d: &DriverSpec) -> Result<()> {
    for (name, v, lo, hi) in [
        ("desired_speed", d.desired_speed, 1.0, 40.0),
        ("time_headway", d.time_headway, 0.3, 5.0),
        ("min_gap", d.min_gap, 0.5, 20.0),
        ("max_accel", d.max_accel, 0.3, 5.0),
        ("comfortable_decel", d.comfortable_decel, 0.5, 8.0),
        ("max_decel", d.max_decel, 1.0, 12.0),
        ("non_yielding_share", d.non_yielding_share, 0.0, 1.0),
    ] {
        if !(v >= lo && v <= hi) {
            return Err(cx.bad(&format!("driver.{name}"), format!("{v} must lie in [{lo}, {hi}]")));
        }
    }
    if d.max_decel < d.comfortable_decel {
        return Err(cx.bad(
            "driver.max_decel",
            format!("{} must be at least comfortable_decel ({})", d.max_decel, d.comfortable_decel),
        ));
    }
    Ok(())
}

/// Walkers: size and speed, nodes on the sidewalks, edges between nodes, crossings at a zebra's kerb ends.
fn resolve_walkers(cx: &Context, w: &WalkerSpec, zebras: &[Zebra]) -> Result<WalkerNetwork> {
    if !(w.radius >= 0.15 && w.radius <= 0.5) {
        return Err(cx.bad("walkers.radius", format!("{} must lie in [0.15, 0.5] m (a person)", w.radius)));
    }
    if !(w.speed[0] >= 0.3 && w.speed[0] <= w.speed[1] && w.speed[1] <= 2.5) {
        return Err(cx.bad("walkers.speed", format!("{:?} must be [min, max] with 0.3 ≤ min ≤ max ≤ 2.5 m/s", w.speed)));
    }
    if w.nodes.len() < 2 || w.edges.is_empty() {
        return Err(cx.bad("walkers", "the network needs at least two nodes and one edge".into()));
    }
    for (i, n) in w.nodes.iter().enumerate() {
        let field = format!("walkers.nodes[{i}]");
        if !finite2(*n) || !cx.extent.contains(n[0], n[1]) {
            return Err(cx.bad(&field, format!("{n:?} must lie inside the world")));
        }
        let kind = cx.region_at(n[0], n[1]);
        if matches!(kind, RegionKind::Road | RegionKind::Zebra) {
            return Err(cx.bad(&field, format!("{n:?} is on the {kind:?}: walkers' nodes stand on sidewalks")));
        }
    }
    let mut adjacency = vec![Vec::new(); w.nodes.len()];
    let mut edges = Vec::with_capacity(w.edges.len());
    for (i, e) in w.edges.iter().enumerate() {
        let field = format!("walkers.edges[{i}]");
        if e.a >= w.nodes.len() || e.b >= w.nodes.len() || e.a == e.b {
            return Err(
                cx.bad(&field, format!("a = {}, b = {} must be two different nodes of {}", e.a, e.b, w.nodes.len()))
            );
        }
        if let Some(z) = e.crossing {
            cx.check_zebra(&format!("{field}.crossing"), z, zebras)?;
            let ends = zebras[z].ends();
            for n in [e.a, e.b] {
                let p = w.nodes[n];
                if ends.iter().map(|q| (q[0] - p[0]).hypot(q[1] - p[1])).fold(f32::INFINITY, f32::min) > 2.0 {
                    return Err(cx.bad(
                        &field,
                        format!("node {n} {p:?} is not at a kerb end of zebra {z} (within 2 m of {ends:?})"),
                    ));
                }
            }
        }
        adjacency[e.a].push(i);
        adjacency[e.b].push(i);
        edges.push((e.a, e.b, e.crossing));
    }
    Ok(WalkerNetwork { radius: w.radius, speed: w.speed, nodes: w.nodes.clone(), edges, adjacency })
}

/// Levels: each traffic level's flow and walkers in range.
fn check_levels(cx: &Context, levels: &LevelsSpec) -> Result<()> {
    for (name, l) in [("light", &levels.light), ("medium", &levels.medium), ("heavy", &levels.heavy)] {
        check_level(l.flow, l.walkers).map_err(|(f, m)| cx.bad(&format!("levels.{name}.{f}"), m))?;
    }
    Ok(())
}

/// Heads and poles: inside the world, heads facing along a road, each for exactly one zebra or road.
fn resolve_heads(cx: &Context, spec: &TrafficSpec, roads: &[String], zebras: &[Zebra]) -> Result<Vec<Head>> {
    for (i, p) in spec.extra_poles.iter().enumerate() {
        if !finite2(*p) || !cx.extent.contains(p[0], p[1]) {
            return Err(cx.bad(&format!("extra_poles[{i}]"), format!("{p:?} must lie inside the world")));
        }
    }
    let mut heads = Vec::with_capacity(spec.heads.len());
    for (i, h) in spec.heads.iter().enumerate() {
        let field = format!("heads[{i}]");
        if !finite2(h.pole) || !cx.extent.contains(h.pole[0], h.pole[1]) {
            return Err(cx.bad(&format!("{field}.pole"), format!("{:?} must lie inside the world", h.pole)));
        }
        let quarter = h.facing_deg / 90.0;
        if !(quarter.is_finite() && (quarter - quarter.round()).abs() < 1e-4) {
            return Err(cx.bad(
                &format!("{field}.facing_deg"),
                format!("{} must be a multiple of 90 (heads face along the roads)", h.facing_deg),
            ));
        }
        let kind = match (&h.zebra, &h.road) {
            (Some(z), None) => {
                cx.check_zebra(&format!("{field}.zebra"), *z, zebras)?;
                HeadKind::Pedestrian(*z)
            }
            (None, Some(r)) => HeadKind::Vehicle(roads.iter().position(|x| x == r).ok_or_else(|| {
                cx.bad(&format!("{field}.road"), format!("no lane is on road {r:?}; the roads are {roads:?}"))
            })?),
            _ => {
                return Err(
                    cx.bad(&field, "give exactly one of `zebra` (a pedestrian head) or `road` (a vehicle head)".into())
                );
            }
        };
        let a = h.facing_deg.to_radians();
        let facing = [a.cos().round(), a.sin().round()];
        heads.push(Head { center: [h.pole[0] + 0.25 * facing[0], h.pole[1] + 0.25 * facing[1]], facing, kind });
    }
    Ok(heads)
}

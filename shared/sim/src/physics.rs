//! Static collision world and the pedestrian's kinematic character controller.
//!
//! All environments of a process share one immutable [`StaticWorld`]: pedestrians
//! of different environments never interact, so each agent is only a pose that is
//! moved with rapier3d's `KinematicCharacterController` against the static
//! colliders (buildings, poles, benches, tree trunks, boundary walls).
//!
//! Invariant: the world is built once from the scene and never mutated, so a move
//! depends only on the pose and the desired translation — the source of the
//! simulator's determinism.

use rapier3d::control::{CharacterLength, KinematicCharacterController};
use rapier3d::prelude::*;

use crate::scene::{Footprint, Scene};

/// The agent's body (docs/design.md §3: capsule r 0.3 m, height 1.8 m).
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct AgentBody {
    /// Capsule radius in metres.
    pub radius: f32,
    /// Total capsule height in metres.
    pub height: f32,
}

impl Default for AgentBody {
    fn default() -> Self {
        AgentBody { radius: 0.3, height: 1.8 }
    }
}

impl crate::traffic::Ground for StaticWorld {
    fn move_body(&self, x: f32, y: f32, dx: f32, dy: f32, dt: f32) -> [f32; 2] {
        let m = self.move_agent(x, y, dx, dy, dt);
        [m.x, m.y]
    }
}

/// Result of one attempted move.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Move {
    /// New x.
    pub x: f32,
    /// New y.
    pub y: f32,
    /// Did the character controller report a hit during the move?
    pub collided: bool,
}

/// The static colliders of a scene plus the character controller.
pub struct StaticWorld {
    bodies: RigidBodySet,
    colliders: ColliderSet,
    broad_phase: BroadPhaseBvh,
    narrow_phase: NarrowPhase,
    controller: KinematicCharacterController,
    shape: Capsule,
    center_height: f32,
}

impl StaticWorld {
    /// Build the colliders of every obstacle of the scene.
    pub fn new(scene: &Scene, body: AgentBody) -> StaticWorld {
        let bodies = RigidBodySet::new();
        let mut colliders = ColliderSet::new();
        for o in &scene.obstacles {
            let collider = match o.footprint {
                Footprint::Box(r) => ColliderBuilder::cuboid(r.width() * 0.5, r.height() * 0.5, o.height * 0.5)
                    .translation(Vector::new((r.min[0] + r.max[0]) * 0.5, (r.min[1] + r.max[1]) * 0.5, o.height * 0.5)),
                Footprint::Cylinder { center, radius } => {
                    // rapier cylinders stand along y; rotate a quarter turn about x to stand along z.
                    ColliderBuilder::cylinder(o.height * 0.5, radius)
                        .translation(Vector::new(center[0], center[1], o.height * 0.5))
                        .rotation(Vector::new(std::f32::consts::FRAC_PI_2, 0.0, 0.0))
                }
            };
            colliders.insert(collider.build());
        }
        let mut broad_phase = BroadPhaseBvh::new();
        let params = IntegrationParameters::default();
        for (handle, c) in colliders.iter() {
            broad_phase.set_aabb(&params, handle, c.compute_aabb());
        }
        let half_segment = (body.height * 0.5 - body.radius).max(0.0);
        let controller = KinematicCharacterController {
            up: Vector::Z,
            offset: CharacterLength::Absolute(0.01),
            slide: true,
            autostep: None,
            snap_to_ground: None,
            ..Default::default()
        };
        StaticWorld {
            bodies,
            colliders,
            broad_phase,
            narrow_phase: NarrowPhase::new(),
            controller,
            shape: Capsule::new_z(half_segment, body.radius),
            center_height: body.height * 0.5 + 0.02,
        }
    }

    /// Move the character from `(x, y)` by `(dx, dy)`, sliding along walls.
    pub fn move_agent(&self, x: f32, y: f32, dx: f32, dy: f32, dt: f32) -> Move {
        let queries = self.broad_phase.as_query_pipeline(
            self.narrow_phase.query_dispatcher(),
            &self.bodies,
            &self.colliders,
            QueryFilter::default(),
        );
        let pos = Pose::from_translation(Vector::new(x, y, self.center_height));
        let mut collided = false;
        let mv =
            self.controller.move_shape(dt, &queries, &self.shape, &pos, Vector::new(dx, dy, 0.0), |_| collided = true);
        Move { x: x + mv.translation.x, y: y + mv.translation.y, collided }
    }

    /// Number of static colliders (obstacles plus walls).
    pub fn num_colliders(&self) -> usize {
        self.colliders.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn free_move_is_exact_and_wall_blocks() {
        let scene = Scene::reference();
        let world = StaticWorld::new(&scene, AgentBody::default());
        assert_eq!(world.num_colliders(), scene.obstacles.len());
        // Open sidewalk: moves exactly.
        let m = world.move_agent(25.0, -6.5, 0.5, 0.0, 0.25);
        assert!(!m.collided);
        assert!((m.x - 25.5).abs() < 1e-4 && (m.y + 6.5).abs() < 1e-4);
        // Walking south into the building line at y = -9 from y = -8.5.
        let m = world.move_agent(25.0, -8.5, 0.0, -0.5, 0.25);
        assert!(m.collided);
        assert!(m.y > -9.0 + 0.29, "stopped outside the wall, got y={}", m.y);
    }
}

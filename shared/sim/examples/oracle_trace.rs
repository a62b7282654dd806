//! Print the oracle's greedy rollout step by step from a validation point.
//! `cargo run --example oracle_trace -- 2`
use pednav_sim::oracle::{Oracle, OracleConfig};
use pednav_sim::{Pedestrian, Pose, Scene, SimConfig, SimWorld};

fn main() -> anyhow::Result<()> {
    let k: usize = std::env::args().nth(1).unwrap_or_else(|| "2".into()).parse()?;
    let steps: u32 = std::env::args().nth(2).unwrap_or_else(|| "40".into()).parse()?;
    let world = SimWorld::new(Scene::reference(), SimConfig::default())?;
    let oracle = Oracle::plan(&world, OracleConfig::default());
    let p = world.scene.validation_points()[k];
    let mut ped = Pedestrian::default();
    ped.reset(Pose::from_degrees(p.x, p.y, p.favourable_yaw_deg));
    for _ in 0..steps {
        let a = oracle.best_action(&world, &ped);
        let v = oracle.value(ped.pose);
        let t = ped.step(a, &world);
        println!(
            "x {:7.2} y {:7.2} yaw {:7.1} V {:8.2} a {:?} r {:6.2} {:?}",
            t.pose.x,
            t.pose.y,
            t.pose.yaw.to_degrees(),
            v,
            a,
            t.reward,
            t.region
        );
        if t.terminated {
            break;
        }
    }
    Ok(())
}

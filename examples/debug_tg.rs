use treacle::app::headless_app;
use treacle::prelude::*;
use treacle::grid::MpmGrid;
fn main() {
    let n: f32 = std::env::args().nth(1).map(|s| s.parse().unwrap()).unwrap_or(16.0);
    let dx = 1.0 / n;
    let cfg = MpmConfig { domain_min: Vec3::ZERO, domain_max: Vec3::new(1.0, 1.0, 2.0 * dx), dx, gravity: Vec3::ZERO, frame_dt: 0.05,
        integrator: IntegratorConfig { flip: std::env::args().nth(3).map(|s| s.parse().unwrap()).unwrap_or(1.0), ..Default::default() }, ..Default::default() };
    let mut mats = Materials::default();
    let nu = 0.05;
    let c0: f32 = std::env::args().nth(2).map(|s| s.parse().unwrap()).unwrap_or(0.2);
    let id = mats.add(FluidMaterial::newtonian("f", 1.0, c0, nu));
    let mut app = headless_app(cfg.clone(), mats);
    let h = dx / 2.0;
    let k = std::f32::consts::PI;
    let a = 0.01;
    let f = move |x: Vec3| Vec3::new(a * (k * x.x).sin() * (k * x.y).cos(), -a * (k * x.x).cos() * (k * x.y).sin(), 0.0);
    let mut b = vec![];
    let m = (cfg.domain_max / h).round().as_ivec3();
    for i in 0..m.x { for j in 0..m.y { for kk in 0..m.z {
        let x = (glam::IVec3::new(i, j, kk).as_vec3() + 0.5) * h;
        b.push(ParticleBundle::new(x, f(x), Vec3::ZERO, h * h * h, 1.0, id));
    }}}
    app.world_mut().spawn_batch(b);
    let e0 = treacle::diagnostics::measure(app.world_mut()).kinetic_energy;
    for fr in 0..8 { app.update(); let e = treacle::diagnostics::measure(app.world_mut()); let c = app.world().resource::<SimulationClock>();
      println!("t={:.3} steps={} KE/KE0={:.5} exact={:.5} vol={:.6} dt={:.3e}", c.time, c.steps, e.kinetic_energy/e0, (-2.0*nu as f64*2.0*9.8696*c.time).exp(), e.volume, c.frame_dt_max); let _ = fr; }
    let g = app.world().resource::<MpmGrid>();
    // compare nodal new_acceleration (from rate evaluation? no: after a frame) -> use force/mass
    let mut num = 0.0; let mut den = 0.0;
    for (idx, node) in g.nodes.iter().enumerate() {
        if node.mass <= 0.0 { continue; }
        let p = g.layout.node_of_index(idx);
        let x = g.layout.node_position(p);
        if x.x < 0.2 || x.x > 0.8 || x.y < 0.2 || x.y > 0.8 { continue; }
        let acc = node.force / node.mass;
        let expect = -nu * 2.0 * k * k * node.velocity;
        num += acc.dot(expect); den += expect.dot(expect);
    }
    println!("interior force/mass vs -nu|k|^2 v: projection ratio {}", num / den);
}

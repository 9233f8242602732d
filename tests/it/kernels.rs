//! ALGORITHM §9 "MPM kernels": K1 (B-spline identities), K2 (P2G/G2P round trip of a linear
//! field with PIC), K3 (momentum conservation of P2G), K4 (forces of a constant stress sum to
//! zero in the interior). Also: the slab-coloured scatter (thermal lattice) and the block-sparse
//! transfers of the MPM grid agree with plain serial loops.
use glam::IVec3;
use treacle::grid::{GridLayout, GridNode, MpmGrid};
use treacle::kernels::{
    G2pResult, Stencil, StepCoefficients, force_particle, g2p_particle, kinematics_particle,
    kinematics_stencil, p2g_particle, p2g_stencil,
};
use treacle::math::{Mat3, Vec3};
use treacle::scatter::BlockPlan;
use treacle::scatter::{ScatterPlan, SharedMut};

/// Deterministic pseudo-random numbers in [0, 1).
struct Lcg(u64);
impl Lcg {
    fn next(&mut self) -> f32 {
        self.0 = self
            .0
            .wrapping_mul(6364136223846793005)
            .wrapping_add(1442695040888963407);
        ((self.0 >> 40) as f32) / ((1u64 << 24) as f32)
    }
    fn vec_in(&mut self, lo: Vec3, hi: Vec3) -> Vec3 {
        lo + (hi - lo) * Vec3::new(self.next(), self.next(), self.next())
    }
}

/// A dense node array over the node box of a unit domain with Δx = 0.1: the kernels address
/// any dense box through its [`GridLayout`] (the step's grid is block-sparse; its transfers run
/// the same kernels on dense block neighbourhoods).
struct Dense {
    layout: GridLayout,
    nodes: Vec<GridNode>,
}

fn grid() -> Dense {
    let layout = GridLayout::new(Vec3::ZERO, Vec3::splat(1.0), 0.1);
    Dense {
        nodes: vec![GridNode::default(); layout.node_count()],
        layout,
    }
}

fn coeffs(dt: f32) -> StepCoefficients {
    StepCoefficients {
        dt,
        w1l1: 2.0 / 3.0,
        w1l4: 2.0 / 3.0,
        w1l6: 7.0 / 6.0,
        w2l2: 1.0 / 3.0,
        w2l5: 2.0 / 3.0,
        l4: 1.0,
        l5: 1.0,
        flip_velocity: 0.0,
        flip_acceleration: 0.0,
    }
}

/// K1: Σw = 1, Σw(xᵢ − x) = 0, Σ∇w = 0, Σ xᵢ ⊗ ∇w = I, at random positions.
/// f32 sums of 27 terms of size ≤ 1: tolerance 1e-5 (≈ 27·ε·|terms|), scaled by 1/Δx for
/// the gradients.
#[test]
fn k1_bspline_identities() {
    let g = grid();
    let mut rng = Lcg(1);
    for _ in 0..1000 {
        let x = rng.vec_in(Vec3::splat(0.2), Vec3::splat(0.8));
        let st = Stencil::new(&g.layout, x);
        let mut sw = 0.0f32;
        let mut sm = Vec3::ZERO;
        let mut sg = Vec3::ZERO;
        let mut cols = [Vec3::ZERO; 3];
        st.for_each(&g.layout, |idx, w, grad| {
            let xi = g.layout.node_position(g.layout.node_of_index(idx));
            sw += w;
            sm += w * (xi - x);
            sg += Vec3::from(grad);
            for (b, col) in cols.iter_mut().enumerate() {
                *col += xi * grad[b];
            }
        });
        assert!((sw - 1.0).abs() < 1e-5, "Σw = {sw}");
        assert!(sm.abs().max_element() < 1e-5 * 0.1, "Σw(xᵢ−x) = {sm}");
        assert!(sg.abs().max_element() < 1e-5 * 10.0, "Σ∇w = {sg}");
        let m = Mat3::from_cols(cols[0], cols[1], cols[2]);
        let err = (m - Mat3::IDENTITY).abs().to_cols_array();
        assert!(err.iter().all(|e| *e < 1e-4), "Σxᵢ⊗∇w = {m}");
    }
}

fn scatter_serial(g: &mut Dense, xs: &[Vec3], ms: &[f32], vs: &[Vec3], as_: &[Vec3]) {
    let layout = g.layout;
    let p = g.nodes.as_mut_ptr();
    for i in 0..xs.len() {
        // SAFETY: single thread.
        unsafe { p2g_particle(&layout, p, xs[i], ms[i], vs[i], as_[i]) };
    }
}

fn normalise(g: &mut Dense) {
    for n in &mut g.nodes {
        if n.mass > 0.0 {
            n.velocity /= n.mass;
            n.acceleration /= n.mass;
        }
    }
}

fn particles(n: usize, seed: u64) -> (Vec<Vec3>, Vec<f32>, Vec<Vec3>, Vec<Vec3>) {
    let mut rng = Lcg(seed);
    let xs: Vec<Vec3> = (0..n)
        .map(|_| rng.vec_in(Vec3::splat(0.25), Vec3::splat(0.75)))
        .collect();
    let ms: Vec<f32> = (0..n).map(|_| 0.5 + rng.next()).collect();
    let vs: Vec<Vec3> = (0..n)
        .map(|_| rng.vec_in(Vec3::splat(-1.0), Vec3::splat(1.0)))
        .collect();
    let as_: Vec<Vec3> = (0..n)
        .map(|_| rng.vec_in(Vec3::splat(-1.0), Vec3::splat(1.0)))
        .collect();
    (xs, ms, vs, as_)
}

/// K3: Σᵢ mᵢvᵢ = Σₚ mₚvₚ and Σᵢ mᵢ = Σₚ mₚ (partition of unity). f64 reference sums;
/// tolerance 1e-4 relative (f32 accumulation over ~27·2000 terms).
#[test]
fn k3_p2g_conserves_mass_and_momentum() {
    let mut g = grid();
    let (xs, ms, vs, as_) = particles(2000, 7);
    scatter_serial(&mut g, &xs, &ms, &vs, &as_);
    // Before normalisation the node "velocity" holds the momentum Σ m w v.
    let mut mg = 0.0f64;
    let mut pg = glam::DVec3::ZERO;
    for n in &g.nodes {
        mg += n.mass as f64;
        pg += glam::Vec3::from(n.velocity).as_dvec3();
    }
    let mp: f64 = ms.iter().map(|m| *m as f64).sum();
    let pp: glam::DVec3 = ms.iter().zip(&vs).map(|(m, v)| (*m * *v).as_dvec3()).sum();
    assert!((mg - mp).abs() < 1e-4 * mp, "mass {mg} vs {mp}");
    for k in 0..3 {
        assert!(
            (pg[k] - pp[k]).abs() < 1e-4 * mp,
            "momentum {k}: {} vs {}",
            pg[k],
            pp[k]
        );
    }
}

/// K2: a linear velocity field v(x) = v₀ + A x survives P2G → G2P (PIC) exactly, and the
/// gathered velocity gradient equals A (quadratic B-splines reproduce linear fields; §2.2).
/// Particles fill the region densely so every stencil node is well supported.
#[test]
fn k2_linear_field_round_trip() {
    let mut g = grid();
    let a_mat = Mat3::from_cols_array(&[0.3, -0.2, 0.1, 0.5, 0.05, -0.4, 0.2, 0.1, -0.35]);
    let v0 = Vec3::new(0.1, -0.2, 0.3);
    let field = |x: Vec3| v0 + a_mat * x;
    // 2 particles per cell per dimension on [0.2, 0.8]^3.
    let h = 0.05;
    let mut xs = vec![];
    for i in 0..12 {
        for j in 0..12 {
            for k in 0..12 {
                xs.push(Vec3::new(
                    0.2 + (i as f32 + 0.5) * h,
                    0.2 + (j as f32 + 0.5) * h,
                    0.2 + (k as f32 + 0.5) * h,
                ));
            }
        }
    }
    let ms = vec![1.0f32; xs.len()];
    let vs: Vec<Vec3> = xs.iter().map(|x| field(*x)).collect();
    let zeros = vec![Vec3::ZERO; xs.len()];
    scatter_serial(&mut g, &xs, &ms, &vs, &zeros);
    normalise(&mut g);
    // Mass-weighted averaging of a linear field is NOT exactly linear at the nodes; what is
    // exact is the APIC/PIC reproduction for interior particles when the nodal field is linear.
    // So impose the linear field on the active nodes and check the gather.
    for (idx, n) in g.nodes.iter_mut().enumerate() {
        if n.mass > 0.0 {
            let xi = g.layout.node_position(g.layout.node_of_index(idx));
            n.velocity = field(xi).into();
            n.new_velocity = field(xi).into();
            n.acceleration = glam::Vec3A::ZERO;
            n.new_acceleration = glam::Vec3A::ZERO;
        }
    }
    let c = coeffs(0.0);
    for x in xs
        .iter()
        .filter(|x| x.cmpgt(Vec3::splat(0.35)).all() && x.cmplt(Vec3::splat(0.65)).all())
    {
        let r: G2pResult = g2p_particle(&g.layout, &g.nodes, *x, *x, Vec3::ZERO, Vec3::ZERO, &c);
        assert!(
            (r.velocity - field(*x)).abs().max_element() < 1e-5,
            "{} vs {}",
            r.velocity,
            field(*x)
        );
        let (l, _) = kinematics_particle(&g.layout, &g.nodes, *x, &c, false);
        let err = (l - a_mat).abs().to_cols_array();
        assert!(err.iter().all(|e| *e < 1e-4), "L = {l} vs {a_mat}");
    }
}

/// K4: a constant stress field gives zero net force on interior nodes (Σₚ Vₚ∇wᵢₚ = 0 for a
/// node whose support is fully covered by a regular particle lattice), and the total force
/// over all nodes is exactly zero (Σᵢ∇wᵢₚ = 0 per particle).
#[test]
fn k4_constant_stress_has_no_interior_force() {
    let mut g = grid();
    let sigma = Mat3::from_cols_array(&[2.0, 0.5, -0.3, 0.5, -1.0, 0.7, -0.3, 0.7, 0.4]);
    let h = 0.05;
    let vol = h * h * h;
    let layout = g.layout;
    let p = g.nodes.as_mut_ptr();
    for i in 0..12 {
        for j in 0..12 {
            for k in 0..12 {
                let x = Vec3::new(
                    0.2 + (i as f32 + 0.5) * h,
                    0.2 + (j as f32 + 0.5) * h,
                    0.2 + (k as f32 + 0.5) * h,
                );
                // SAFETY: single thread.
                unsafe { force_particle(&layout, p, x, vol * sigma) };
            }
        }
    }
    let mut total = glam::DVec3::ZERO;
    let mut scale = 0.0f32;
    let mut abs_sum = 0.0f64;
    for (idx, n) in g.nodes.iter().enumerate() {
        total += n.force.as_dvec3();
        abs_sum += n.force.length() as f64;
        scale = scale.max(n.force.abs().max_element());
        let node = layout.node_of_index(idx);
        // interior: the node's support [x−1.5Δx, x+1.5Δx] lies inside the particle region
        if node.cmpge(IVec3::splat(4)).all() && node.cmple(IVec3::splat(6)).all() {
            assert!(
                n.force.abs().max_element() < 1e-6,
                "interior node {node}: {}",
                n.force
            );
        }
    }
    assert!(scale > 1e-4, "boundary nodes must carry the traction");
    // Round-off of f32 accumulation is O(ε·Σ|terms|); 1e-5·Σ|fᵢ| is ~100 ε and still far below
    // any real imbalance (a missing particle would leave ~Σ|fᵢ|/1000).
    assert!(
        total.abs().max_element() < 1e-5 * abs_sum,
        "Σf = {total}, Σ|f| = {abs_sum}"
    );
}

/// The slab-coloured parallel scatter gives bit-identical nodes to itself run serially and
/// the same sums as a plain loop (order differs, so compare to f32 rounding).
#[test]
fn scatter_plan_is_deterministic() {
    let (xs, ms, vs, as_) = particles(20000, 11);
    let run = || {
        let mut g = grid();
        let mut plan = ScatterPlan::default();
        plan.build(&g.layout, xs.iter().copied());
        let layout = g.layout;
        let nodes = SharedMut(g.nodes.as_mut_ptr());
        plan.run(|i| unsafe { p2g_particle(&layout, nodes.get(), xs[i], ms[i], vs[i], as_[i]) });
        g.nodes
    };
    let a: Vec<GridNode> = run();
    let b: Vec<GridNode> = run();
    assert_eq!(a, b);
    let mut s = grid();
    scatter_serial(&mut s, &xs, &ms, &vs, &as_);
    for (x, y) in a.iter().zip(&s.nodes) {
        assert!((x.mass - y.mass).abs() <= 1e-5 * (1.0 + y.mass));
    }
}

/// The block-sparse scatter (particles ordered by block, one dense neighbourhood per block,
/// colour phases) allocates only the reached blocks and gives the sums of a plain serial loop on
/// a dense grid; gathers through block neighbourhoods agree with dense gathers.
///
/// Tolerance: both sides sum the same k terms of a node in different orders (the block scatter
/// forms up to 8 partial sums and adds them). A recursive f32 sum of k terms is within
/// (k − 1)ε·Σ|terms| of the exact sum, so the two differ by at most 2kε·Σ|terms|; k is counted
/// per node and Σ|terms| is scattered with |v|.
#[test]
fn block_plan_scatter_matches_dense_loop() {
    let (xs, ms, vs, as_) = particles(20000, 13);
    let mut sparse = MpmGrid::new(Vec3::ZERO, Vec3::splat(1.0), 0.1);
    let layout = sparse.layout;
    let stencils: Vec<Stencil> = xs.iter().map(|x| Stencil::new(&layout, *x)).collect();
    let mut plan = BlockPlan::default();
    plan.build(&layout, stencils.iter().map(|s| s.base));
    let mut keys = Vec::new();
    plan.reached_blocks(&layout, &mut keys);
    keys.sort_unstable();
    keys.dedup();
    sparse.allocate(&keys);
    let mut nodes = std::mem::take(&mut sparse.nodes);
    plan.scatter(
        &sparse,
        &mut nodes,
        |n: &mut GridNode, h: &GridNode| {
            n.mass += h.mass;
            n.velocity += h.velocity;
            n.acceleration += h.acceleration;
        },
        |i, local, hood| unsafe {
            p2g_stencil(local, hood.as_mut_ptr(), &stencils[i], ms[i], vs[i], as_[i])
        },
    );
    sparse.nodes = nodes;
    let mut dense = grid();
    scatter_serial(&mut dense, &xs, &ms, &vs, &as_);
    let mut abs = grid();
    let abs_vs: Vec<Vec3> = vs.iter().map(|v| v.abs()).collect();
    scatter_serial(&mut abs, &xs, &ms, &abs_vs, &as_);
    let mut terms = vec![0u32; layout.node_count()];
    for st in &stencils {
        st.for_each_weight(&layout, |idx, _| terms[idx] += 1);
    }
    // Every node with mass has storage, and agrees with the dense sum.
    let mut checked = 0;
    for (idx, d) in dense.nodes.iter().enumerate() {
        let c = layout.node_of_index(idx);
        let bound = 2.0 * terms[idx] as f32 * f32::EPSILON;
        match sparse.index(c) {
            Some(i) => {
                let s = &sparse.nodes[i];
                assert!(
                    (s.mass - d.mass).abs() <= bound * d.mass,
                    "{c}: {} vs {}",
                    s.mass,
                    d.mass
                );
                let tol = bound * Vec3::from(abs.nodes[idx].velocity).max_element();
                let diff = Vec3::from(s.velocity - d.velocity).abs().max_element();
                assert!(diff <= tol, "{c}: momentum differs by {diff} > {tol}");
                checked += (d.mass > 0.0) as usize;
            }
            None => assert_eq!(d.mass, 0.0, "node {c} has mass but no storage"),
        }
    }
    // Particles in [0.25, 0.75]³ at Δx = 0.1 have stencil bases 2..=6, so nodes 2..=8 of each
    // axis receive mass: 7³ nodes, all compared above.
    assert_eq!(checked, 343, "nodes with mass");
    // Fewer nodes than the dense box: the particles fill [0.1, 0.9]³ of a padded 17³ box.
    assert!(sparse.nodes.len() < dense.nodes.len());
    // Gather: block neighbourhoods give exactly the dense result.
    for n in &mut sparse.nodes {
        n.new_velocity = n.velocity * 2.0;
    }
    for n in &mut dense.nodes {
        n.new_velocity = n.velocity * 2.0;
    }
    let mut out = Vec::new();
    let c = coeffs(1e-3);
    plan.gather_into(&sparse, &sparse.nodes, &mut out, |i, local, hood| {
        kinematics_stencil(local, hood, &stencils[i], &c, false).0
    });
    // On identical node values the neighbourhood gather is the dense gather bit for bit (same
    // weights, same order): copy the sparse values into the dense array first.
    for (i, n) in sparse.nodes.iter().enumerate() {
        dense.nodes[layout.index(sparse.node_of_index(i))] = *n;
    }
    for (i, l) in out.iter().enumerate() {
        let d = kinematics_stencil(&layout, &dense.nodes, &stencils[i], &c, false).0;
        assert_eq!(*l, d, "particle {i}");
    }
}

/// The transfer kernels sum each stencil row first (`Stencil::for_each_row`); they must give
/// the 27-node sums Σ wᵢ fᵢ, Σ fᵢ ⊗ ∇wᵢ and −Vσ∇wᵢ, here formed node by node in f64 from the
/// same 1-D weights, at random positions and random node fields.
///
/// Tolerance: each f32 result is a sum of at most 27 products of at most 4 rounded factors,
/// summed in some order, so it is within (27 + 4)ε·Σ|terms| of the exact sum (the first-order
/// bound γₙ ≈ nε of a recursive sum); twice that is allowed. A wrong weight, a transposed
/// gradient or a missed node is off by a sizeable fraction of Σ|terms|.
#[test]
fn row_form_kernels_match_the_node_by_node_sums() {
    use glam::DVec3;
    use treacle::kernels::{displacement_gradient_stencil, force_stencil, g2p_stencil};
    use treacle::step::symplectic_euler::{first_order_coefficients, g2p_first_order};
    let mut g = grid();
    let mut rng = Lcg(7);
    let unit = |rng: &mut Lcg| rng.vec_in(Vec3::splat(-1.0), Vec3::splat(1.0));
    for n in &mut g.nodes {
        n.velocity = unit(&mut rng).into();
        n.new_velocity = unit(&mut rng).into();
        n.acceleration = unit(&mut rng).into();
        n.new_acceleration = unit(&mut rng).into();
    }
    let layout = g.layout;
    let bound = |abs: f64| 2.0 * 31.0 * f32::EPSILON as f64 * abs;
    let close = |what: &str, got: Vec3, exact: DVec3, abs: DVec3| {
        for a in 0..3 {
            let err = (got[a] as f64 - exact[a]).abs();
            assert!(
                err <= bound(abs[a]),
                "{what}[{a}]: {} vs {} (Σ|terms| {})",
                got[a],
                exact[a],
                abs[a]
            );
        }
    };
    let dt = 0.01;
    let fo = first_order_coefficients(dt, 0.0);
    let c = coeffs(dt as f32);
    for p in 0..200 {
        let x = rng.vec_in(Vec3::splat(0.2), Vec3::splat(0.8));
        let st = Stencil::new(&layout, x);
        // Node by node, in f64: (storage index, w, ∇w) of the 27 nodes.
        let mut stencil = Vec::new();
        for i in 0..3 {
            for j in 0..3 {
                for k in 0..3 {
                    let (wx, wy, wz) = (st.w[0][i] as f64, st.w[1][j] as f64, st.w[2][k] as f64);
                    let (dx, dy, dz) = (st.dw[0][i] as f64, st.dw[1][j] as f64, st.dw[2][k] as f64);
                    let idx = layout.index(st.base + IVec3::new(i as i32, j as i32, k as i32));
                    let grad = DVec3::new(dx * wy * wz, wx * dy * wz, wx * wy * dz);
                    stencil.push((idx, wx * wy * wz, grad));
                }
            }
        }
        // Σ w f and Σ f ⊗ ∇w of a node field, with the sums of the terms' magnitudes.
        let field = |f: &dyn Fn(&GridNode) -> DVec3| {
            let (mut sw, mut sw_abs) = (DVec3::ZERO, DVec3::ZERO);
            let (mut sg, mut sg_abs) = ([DVec3::ZERO; 3], [DVec3::ZERO; 3]);
            for &(idx, w, grad) in &stencil {
                let v = f(&g.nodes[idx]);
                sw += w * v;
                sw_abs += w.abs() * v.abs();
                for b in 0..3 {
                    sg[b] += v * grad[b];
                    sg_abs[b] += v.abs() * grad[b].abs();
                }
            }
            (sw, sw_abs, sg, sg_abs)
        };
        let d = |v: glam::Vec3A| Vec3::from(v).as_dvec3();
        let (v_new, v_new_abs, l_new, l_new_abs) = field(&|n| d(n.new_velocity));
        let (a_new, a_new_abs, _, _) = field(&|n| d(n.new_acceleration));
        let (v_old, v_old_abs, _, _) = field(&|n| d(n.velocity));
        // First-order G2P (PIC): velocity, acceleration, position and Lⁿ⁺¹.
        let v = unit(&mut rng);
        let r = g2p_first_order(&layout, &g.nodes, &st, x, v, &fo);
        close("first-order velocity", r.velocity, v_new, v_new_abs);
        close("first-order acceleration", r.acceleration, a_new, a_new_abs);
        let dx_exact = x.as_dvec3() + dt * v_new;
        let dx_abs = x.abs().as_dvec3() + dt * v_new_abs;
        close("first-order position", r.position, dx_exact, dx_abs);
        for b in 0..3 {
            let col = r.velocity_gradient.col(b);
            close("first-order L", col, l_new[b], l_new_abs[b]);
        }
        // FLIP: vₚ + Σ w (vᵢⁿ⁺¹ − vᵢⁿ).
        let flip = g2p_first_order(
            &layout,
            &g.nodes,
            &st,
            x,
            v,
            &first_order_coefficients(dt, 1.0),
        );
        let v_abs = v.abs().as_dvec3() + v_new_abs + v_old_abs;
        close(
            "first-order FLIP velocity",
            flip.velocity,
            v.as_dvec3() + v_new - v_old,
            v_abs,
        );
        // GS4 G2P (PIC): velocity and acceleration.
        let r = g2p_stencil(&layout, &g.nodes, &st, x, v, Vec3::ZERO, &c);
        close("GS4 velocity", r.velocity, v_new, v_new_abs);
        close("GS4 acceleration", r.acceleration, a_new, a_new_abs);
        // Velocity gradient L̃ of ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ and Ĝ of W₁Λ₁Δt vᵢ + W₂Λ₂Δt² aᵢ.
        let s = (c.w1l4 * c.dt) as f64;
        let (gv, ga) = ((c.w1l1 * c.dt) as f64, (c.w2l2 * c.dt * c.dt) as f64);
        let (_, _, l_t, l_t_abs) = field(&|n| d(n.velocity) + s * d(n.acceleration));
        let (_, _, g_hat, g_abs) = field(&|n| gv * d(n.velocity) + ga * d(n.acceleration));
        let (l, gm) = kinematics_stencil(&layout, &g.nodes, &st, &c, true);
        let (l_only, _) = kinematics_stencil(&layout, &g.nodes, &st, &c, false);
        let half = 0.5 * c.dt as f64;
        let (_, _, g_disp, g_disp_abs) = field(&|n| half * (d(n.velocity) + d(n.new_velocity)));
        let disp = displacement_gradient_stencil(&layout, &g.nodes, &st, &c);
        for b in 0..3 {
            close("L̃", l.col(b), l_t[b], l_t_abs[b]);
            close("L̃ alone", l_only.col(b), l_t[b], l_t_abs[b]);
            close("Ĝ", gm.col(b), g_hat[b], g_abs[b]);
            close(
                "displacement gradient",
                disp.col(b),
                g_disp[b],
                g_disp_abs[b],
            );
        }
        // Scatters into a zeroed copy: P2G (mass, m·v, m·a) and the force −Vσ∇w.
        let mut out = grid();
        let (m, a) = (0.5 + rng.next(), unit(&mut rng));
        let sigma = Mat3::from_cols(unit(&mut rng), unit(&mut rng), unit(&mut rng)) * 100.0;
        // SAFETY: single thread, the stencil lies inside the dense box.
        unsafe {
            p2g_stencil(&layout, out.nodes.as_mut_ptr(), &st, m, v, a);
            force_stencil(&layout, out.nodes.as_mut_ptr(), &st, sigma);
        }
        let sd = sigma.as_dmat3();
        let m = m as f64;
        for &(idx, w, grad) in &stencil {
            let n = &out.nodes[idx];
            let mass_err = (n.mass as f64 - w * m).abs();
            assert!(
                mass_err <= bound(w * m),
                "particle {p}: mass {} vs {}",
                n.mass,
                w * m
            );
            let mv = w * m * v.as_dvec3();
            close("m·v", Vec3::from(n.velocity), mv, mv.abs());
            let ma = w * m * a.as_dvec3();
            close("m·a", Vec3::from(n.acceleration), ma, ma.abs());
            let f = -(sd * grad);
            let f_abs = sd.abs() * grad.abs();
            close("force", Vec3::from(n.force), f, f_abs);
        }
    }
}

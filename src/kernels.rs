//! Quadratic B-spline interpolation and the per-particle transfer kernels (ALGORITHM §2.2,
//! §2.5, §2.9, §2.12), as plain functions usable without an App.
//!
//! The systems in [`crate::step`] call exactly these functions; the tests in `tests/it/kernels.rs`
//! and the criterion benches call them on plain slices.
use glam::{IVec3, Mat3A, Vec3A};

use crate::grid::{GridLayout, GridNode};
use crate::math::{Mat3, Real, Vec3};

pub use crate::math::fast_floor;

/// Quadratic B-spline N(x) and its derivative N'(x) (ALGORITHM §2.2).
#[inline(always)]
pub fn bspline(x: Real) -> (Real, Real) {
    let ax = x.abs();
    if ax < 0.5 {
        (0.75 - x * x, -2.0 * x)
    } else if ax < 1.5 {
        let t = 1.5 - ax;
        (0.5 * t * t, -x.signum() * t)
    } else {
        (0.0, 0.0)
    }
}

/// Weights of one particle on its 3×3×3 node stencil: base node and 1-D weights / gradients
/// (the gradients already carry the 1/Δx factor).
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct Stencil {
    /// Lowest node of the stencil: ⌊x/Δx − ½⌋ (in grid node coordinates).
    pub base: IVec3,
    /// `w[axis][o]` = N((x − x_{base+o})/Δx) along `axis`.
    pub w: [[Real; 3]; 3],
    /// `dw[axis][o]` = N'(·)/Δx.
    pub dw: [[Real; 3]; 3],
}

impl Stencil {
    /// The stencil of a particle at world position `x` (clamped into the node box: a particle
    /// outside it is reported by the monitor; clamping only keeps memory access in bounds).
    #[inline(always)]
    pub fn new(grid: &GridLayout, x: Vec3) -> Self {
        let (base, offset) = Self::locate(grid, x);
        Self::from_offset(grid, base, offset)
    }

    /// The base node of [`Stencil::new`] and the particle's distance from it in cells on each
    /// axis (in \[0.5, 1.5) unless the base was clamped): all the weights depend on.
    #[inline(always)]
    pub fn locate(grid: &GridLayout, x: Vec3) -> (IVec3, Vec3) {
        let xi = (x - grid.origin) * grid.inv_dx;
        let (lo, hi) = grid.base_bounds();
        let base = IVec3::new(
            fast_floor(xi.x - 0.5),
            fast_floor(xi.y - 0.5),
            fast_floor(xi.z - 0.5),
        )
        .clamp(lo, hi);
        (base, xi - base.as_vec3())
    }

    /// The weights and gradients of a particle at distance `offset` (cells) from node `base`,
    /// as [`Stencil::locate`] gives them.
    #[inline(always)]
    pub fn from_offset(grid: &GridLayout, base: IVec3, offset: Vec3) -> Self {
        let mut w = [[0.0; 3]; 3];
        let mut dw = [[0.0; 3]; 3];
        for axis in 0..3 {
            // Distance to the first stencil node in cells, in [0.5, 1.5) for an unclamped
            // particle: the three nodes are at fx, fx−1, fx−2 (closed forms of §2.2).
            let fx = offset[axis];
            let d0 = 1.5 - fx;
            let d1 = fx - 1.0;
            let d2 = fx - 0.5;
            if (0.5..1.5).contains(&fx) {
                w[axis] = [0.5 * d0 * d0, 0.75 - d1 * d1, 0.5 * d2 * d2];
                dw[axis] = [-d0 * grid.inv_dx, -2.0 * d1 * grid.inv_dx, d2 * grid.inv_dx];
            } else {
                // Clamped (particle outside the node box): general formula.
                for o in 0..3 {
                    let (n, dn) = bspline(fx - o as Real);
                    w[axis][o] = n;
                    dw[axis][o] = dn * grid.inv_dx;
                }
            }
        }
        Self { base, w, dw }
    }

    /// Visits the 27 nodes: `f(storage index, weight)` (no gradients).
    #[inline(always)]
    pub fn for_each_weight(&self, grid: &GridLayout, mut f: impl FnMut(usize, Real)) {
        let wz = self.w[2];
        self.for_each_row(grid, |row, r| {
            f(row, r.z * wz[0]);
            f(row + 1, r.z * wz[1]);
            f(row + 2, r.z * wz[2]);
        });
    }

    /// Visits the 27 nodes: `f(storage index, weight, weight gradient)`.
    ///
    /// The gradient ∇w = (N'ₓN_yN_z, NₓN'_yN_z, NₓN_yN'_z)/Δx is formed as one SIMD product of a
    /// per-(i, j) row vector (N'ₓN_y, NₓN'_y, NₓN_y) and a per-k vector (N_z, N_z, N'_z).
    #[inline(always)]
    pub fn for_each(&self, grid: &GridLayout, mut f: impl FnMut(usize, Real, Vec3A)) {
        let wz = self.w[2];
        let kz = [0, 1, 2].map(|k| Vec3A::new(wz[k], wz[k], self.dw[2][k]));
        self.for_each_row(grid, |row, r| {
            f(row, r.z * wz[0], r * kz[0]);
            f(row + 1, r.z * wz[1], r * kz[1]);
            f(row + 2, r.z * wz[2], r * kz[2]);
        });
    }

    /// Visits the 9 rows (i, j) of the stencil: `f(storage index of node (i, j, 0), r)` with
    /// r = (N'ₓN_y, NₓN'_y, NₓN_y) (the gradient factors carry 1/Δx). The row's nodes are that
    /// index and the next two; node k has the weight r.z N_z\[k\] and the gradient
    /// (r.x N_z\[k\], r.y N_z\[k\], r.z N'_z\[k\]) — see [`Stencil::z_factors`].
    ///
    /// The kernels below sum along each row first and weight the row sums by r: the 27-node sums
    /// factor as Σᵢⱼ rᵢⱼ (Σₖ N_z\[k\] ·), which takes about half the products of a visit of the 27
    /// nodes with their weights and gradients ([`Stencil::for_each`]).
    #[inline(always)]
    pub fn for_each_row(&self, grid: &GridLayout, mut f: impl FnMut(usize, Vec3A)) {
        let dz = grid.dims.z as usize;
        let dyz = grid.dims.y as usize * dz;
        let b = grid.index(self.base);
        for i in 0..3 {
            let (wx, dwx) = (self.w[0][i], self.dw[0][i]);
            for j in 0..3 {
                let (wy, dwy) = (self.w[1][j], self.dw[1][j]);
                f(
                    b + i * dyz + j * dz,
                    Vec3A::new(dwx * wy, wx * dwy, wx * wy),
                );
            }
        }
    }

    /// N_z\[k\] and N'_z\[k\] of the three nodes of a row, each splatted to a vector.
    #[inline(always)]
    pub fn z_factors(&self) -> ([Vec3A; 3], [Vec3A; 3]) {
        (self.w[2].map(Vec3A::splat), self.dw[2].map(Vec3A::splat))
    }
}

/// Constants of one step needed by the kernels (ALGORITHM §1.1; [`crate::step::schedule::StepContext`]
/// builds them from the GS4 parameters and Δt).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct StepCoefficients {
    /// Δt \[s\] (0 for the start-up rate evaluation).
    pub dt: Real,
    /// W₁Λ₁.
    pub w1l1: Real,
    /// W₁Λ₄.
    pub w1l4: Real,
    /// W₁Λ₆ (the effective-mass factor).
    pub w1l6: Real,
    /// W₂Λ₂.
    pub w2l2: Real,
    /// W₂Λ₅.
    pub w2l5: Real,
    /// λ₄.
    pub l4: Real,
    /// λ₅.
    pub l5: Real,
    /// FLIP fraction for the velocity.
    pub flip_velocity: Real,
    /// FLIP fraction for the acceleration.
    pub flip_acceleration: Real,
}

/// Scatter of one particle's mass, momentum and m·a (§2.5, eq. 31, before normalisation).
///
/// # Safety
/// `nodes` must point to a node array laid out by `grid`, and no other thread may access the 27
/// nodes of this particle's stencil concurrently (guaranteed by [`crate::scatter`]).
#[inline(always)]
pub unsafe fn p2g_particle(
    grid: &GridLayout,
    nodes: *mut GridNode,
    x_tilde: Vec3,
    mass: Real,
    velocity: Vec3,
    acceleration: Vec3,
) {
    // SAFETY: forwarded contract.
    unsafe {
        p2g_stencil(
            grid,
            nodes,
            &Stencil::new(grid, x_tilde),
            mass,
            velocity,
            acceleration,
        )
    }
}

/// [`p2g_particle`] with precomputed weights.
///
/// # Safety
/// As [`p2g_particle`].
#[inline(always)]
pub unsafe fn p2g_stencil(
    grid: &GridLayout,
    nodes: *mut GridNode,
    st: &Stencil,
    mass: Real,
    velocity: Vec3,
    acceleration: Vec3,
) {
    // SAFETY: forwarded contract.
    unsafe { scatter_transfer::<true>(grid, nodes, st, mass, velocity, acceleration) }
}

/// [`p2g_stencil`] without the acceleration: mass and momentum only (the first-order schemes,
/// whose grid update does not use the transferred aᵢ).
///
/// # Safety
/// As [`p2g_particle`].
#[inline(always)]
pub unsafe fn p2g_stencil_momentum(
    grid: &GridLayout,
    nodes: *mut GridNode,
    st: &Stencil,
    mass: Real,
    velocity: Vec3,
) {
    // SAFETY: forwarded contract.
    unsafe { scatter_transfer::<false>(grid, nodes, st, mass, velocity, Vec3::ZERO) }
}

/// The loop of [`p2g_stencil`] (`WITH_A`) and [`p2g_stencil_momentum`].
///
/// # Safety
/// As [`p2g_particle`].
#[inline(always)]
unsafe fn scatter_transfer<const WITH_A: bool>(
    grid: &GridLayout,
    nodes: *mut GridNode,
    st: &Stencil,
    mass: Real,
    velocity: Vec3,
    acceleration: Vec3,
) {
    let mv = Vec3A::from(velocity) * mass;
    let ma = Vec3A::from(acceleration) * mass;
    let (wz, _) = st.z_factors();
    st.for_each_row(grid, |idx, r| {
        // The row's share NₓN_y of m, m·v and m·a, spread over its three nodes by N_z.
        let (row_m, row_mv, row_ma) = (r.z * mass, r.z * mv, r.z * ma);
        let add = |k: usize| {
            // SAFETY: idx + k is in bounds (stencil clamped) and exclusive per the caller's
            // contract.
            let n = unsafe { &mut *nodes.add(idx + k) };
            n.mass += row_m * st.w[2][k];
            n.velocity += row_mv * wz[k];
            if WITH_A {
                n.acceleration += row_ma * wz[k];
            }
        };
        add(0);
        add(1);
        add(2);
    });
}

/// Scatter of one particle's internal force f̃ᵢ += −Ṽ σ̃ ∇w̃ (§2.9, eq. 35).
///
/// # Safety
/// As [`p2g_particle`].
#[inline(always)]
pub unsafe fn force_particle(
    grid: &GridLayout,
    nodes: *mut GridNode,
    x_tilde: Vec3,
    v_sigma: Mat3,
) {
    // SAFETY: forwarded contract.
    unsafe { force_stencil(grid, nodes, &Stencil::new(grid, x_tilde), v_sigma) }
}

/// [`force_particle`] with precomputed weights, in row form ([`Stencil::for_each_row`]): with
/// the columns cₐ of Ṽσ̃, node k of row r receives −((c₀ r.x + c₁ r.y) N_z\[k\] + c₂ r.z N'_z\[k\]).
///
/// # Safety
/// As [`p2g_particle`].
#[inline(always)]
pub unsafe fn force_stencil(grid: &GridLayout, nodes: *mut GridNode, st: &Stencil, v_sigma: Mat3) {
    let m = Mat3A::from(v_sigma);
    let (wz, dz) = st.z_factors();
    st.for_each_row(grid, |idx, r| {
        let along = m.x_axis * r.x + m.y_axis * r.y;
        let across = m.z_axis * r.z;
        for k in 0..3 {
            // SAFETY: as in p2g_particle.
            let n = unsafe { &mut *nodes.add(idx + k) };
            n.force -= along * wz[k] + across * dz[k];
        }
    });
}

/// Velocity gradient at the predicted configuration: L̃ = Σ ṽᵢ ⊗ ∇w̃, ṽᵢ = vᵢ + W₁Λ₄Δt aᵢ (§2.3 S4).
/// Also returns Ĝ = Σ (W₁Λ₁Δt vᵢ + W₂Λ₂Δt² aᵢ) ⊗ ∇w̃ when `want_g` (for F̃, D16).
#[inline(always)]
pub fn kinematics_particle(
    grid: &GridLayout,
    nodes: &[GridNode],
    x_tilde: Vec3,
    c: &StepCoefficients,
    want_g: bool,
) -> (Mat3, Mat3) {
    kinematics_stencil(grid, nodes, &Stencil::new(grid, x_tilde), c, want_g)
}

/// Σₖ wₖ fₖ over the three nodes of a stencil row, with `w` one of the [`Stencil::z_factors`].
#[inline(always)]
pub fn row_sum(w: &[Vec3A; 3], f: [Vec3A; 3]) -> Vec3A {
    w[0] * f[0] + w[1] * f[1] + w[2] * f[2]
}

/// Adds one stencil row's share of Σₖ fₖ ⊗ ∇wₖ to the columns `acc`, for node values
/// `f` = \[f₀, f₁, f₂\] and the row factors `r` of [`Stencil::for_each_row`]:
/// (r.x Σₖ N_z fₖ, r.y Σₖ N_z fₖ, r.z Σₖ N'_z fₖ), with `z` = [`Stencil::z_factors`].
#[inline(always)]
pub fn add_row_gradient(
    acc: &mut [Vec3A; 3],
    z: &([Vec3A; 3], [Vec3A; 3]),
    r: Vec3A,
    f: [Vec3A; 3],
) {
    let along = row_sum(&z.0, f);
    let across = row_sum(&z.1, f);
    acc[0] += r.x * along;
    acc[1] += r.y * along;
    acc[2] += r.z * across;
}

/// [`kinematics_particle`] with precomputed weights, in row form ([`Stencil::for_each_row`]).
#[inline(always)]
pub fn kinematics_stencil(
    grid: &GridLayout,
    nodes: &[GridNode],
    st: &Stencil,
    c: &StepCoefficients,
    want_g: bool,
) -> (Mat3, Mat3) {
    let s = c.w1l4 * c.dt;
    let z = st.z_factors();
    let mut l = [Vec3A::ZERO; 3];
    let vt = |n: &GridNode| n.velocity + s * n.acceleration;
    if !want_g {
        st.for_each_row(grid, |idx, r| {
            add_row_gradient(&mut l, &z, r, [0, 1, 2].map(|k| vt(&nodes[idx + k])));
        });
        return (Mat3::from(Mat3A::from_cols(l[0], l[1], l[2])), Mat3::ZERO);
    }
    let mut g = [Vec3A::ZERO; 3];
    let gv = c.w1l1 * c.dt;
    let ga = c.w2l2 * c.dt * c.dt;
    st.for_each_row(grid, |idx, r| {
        let n = [0, 1, 2].map(|k| &nodes[idx + k]);
        add_row_gradient(&mut l, &z, r, n.map(vt));
        add_row_gradient(
            &mut g,
            &z,
            r,
            n.map(|n| gv * n.velocity + ga * n.acceleration),
        );
    });
    (
        Mat3::from(Mat3A::from_cols(l[0], l[1], l[2])),
        Mat3::from(Mat3A::from_cols(g[0], g[1], g[2])),
    )
}

/// Result of the grid-to-particle gather of one particle.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct G2pResult {
    /// Blended new velocity vₚⁿ⁺¹.
    pub velocity: Vec3,
    /// Blended new acceleration aₚⁿ⁺¹.
    pub acceleration: Vec3,
    /// Position xₚⁿ⁺¹ = xₚⁿ + Δt/2 (vₚⁿ + v_FLIP) (eq. 45, D6).
    pub position: Vec3,
    /// Position moved with the grid displacement, xₚⁿ + Δt/2 Σ w̃ (vᵢⁿ + vᵢⁿ⁺¹): the field F
    /// is advanced with (D7; [`SolidMotion::GridVelocity`](crate::config::SolidMotion)).
    pub grid_position: Vec3,
}

/// G2P with PIC/FLIP blend and the position update (§2.12–2.13).
///
/// **Deviation from ALGORITHM §2.12 (measured).** §2.12 writes the FLIP velocity as
/// vₚ + λ₄Δt aₚ + Σ w̃ δvᵢ with δvᵢ = vᵢⁿ⁺¹ − vᵢⁿ − λ₄Δt aᵢⁿ. That adds
/// λ₄Δt (aₚ − Σ w̃ aᵢⁿ) to vₚ every step: the part of the particle acceleration the grid cannot
/// see, which the acceleration FLIP update never corrects. In a Taylor–Green cell with pure
/// FLIP (c₀ = 10 m/s, Δx = 1/16) the kinetic energy grew 4·10⁶-fold in 0.4 s at a Δt inside
/// the predicted limit. We use the standard FLIP increment vₚ + Σ w̃ (vᵢⁿ⁺¹ − vᵢⁿ), which is
/// identical whenever aₚ lies in the range of the interpolation (e.g. free fall, the consistent
/// start), keeps the grid update exactly GS4, and is stable (`tests/it/mpm.rs`, M3).
#[inline(always)]
pub fn g2p_particle(
    grid: &GridLayout,
    nodes: &[GridNode],
    x: Vec3,
    x_tilde: Vec3,
    v: Vec3,
    a: Vec3,
    c: &StepCoefficients,
) -> G2pResult {
    g2p_stencil(grid, nodes, &Stencil::new(grid, x_tilde), x, v, a, c)
}

/// [`g2p_particle`] with precomputed weights.
#[inline(always)]
pub fn g2p_stencil(
    grid: &GridLayout,
    nodes: &[GridNode],
    st: &Stencil,
    x: Vec3,
    v: Vec3,
    a: Vec3,
    c: &StepCoefficients,
) -> G2pResult {
    let [v_pic, a_pic, v_old, a_old] = gather_node_fields(grid, nodes, st);
    // FLIP increment Σ w̃ (vᵢⁿ⁺¹ − vᵢⁿ), including the collision change.
    let v_flip = v + (v_pic - v_old);
    let a_flip = a + (a_pic - a_old);
    blend_flip(x, v, [v_pic, a_pic], [v_flip, a_flip], v_old, c)
}

/// Σ w̃ of the node fields G2P reads: \[vⁿ⁺¹, aⁿ⁺¹, vⁿ, aⁿ\] (row form, [`Stencil::for_each_row`]).
#[inline(always)]
fn gather_node_fields(grid: &GridLayout, nodes: &[GridNode], st: &Stencil) -> [Vec3; 4] {
    let mut v_pic = Vec3A::ZERO;
    let mut a_pic = Vec3A::ZERO;
    let mut v_old = Vec3A::ZERO;
    let mut a_old = Vec3A::ZERO;
    let (wz, _) = st.z_factors();
    st.for_each_row(grid, |idx, r| {
        let n = [0, 1, 2].map(|k| &nodes[idx + k]);
        let wxy = Vec3A::splat(r.z);
        v_pic += wxy * row_sum(&wz, n.map(|n| n.new_velocity));
        a_pic += wxy * row_sum(&wz, n.map(|n| n.new_acceleration));
        v_old += wxy * row_sum(&wz, n.map(|n| n.velocity));
        a_old += wxy * row_sum(&wz, n.map(|n| n.acceleration));
    });
    [v_pic, a_pic, v_old, a_old].map(Vec3::from)
}

/// The PIC/FLIP blend of §2.12 and the trapezoidal position updates (`v_old` = Σ w̃ vᵢⁿ).
#[inline(always)]
fn blend_flip(
    x: Vec3,
    v: Vec3,
    pic: [Vec3; 2],
    flip: [Vec3; 2],
    v_old: Vec3,
    c: &StepCoefficients,
) -> G2pResult {
    let ([v_pic, a_pic], [v_flip, a_flip]) = (pic, flip);
    let (fv, fa) = (c.flip_velocity, c.flip_acceleration);
    G2pResult {
        velocity: v_pic + fv * (v_flip - v_pic),
        acceleration: a_pic + fa * (a_flip - a_pic),
        position: x + (0.5 * c.dt) * (v + v_flip),
        grid_position: x + (0.5 * c.dt) * (v_old + v_pic),
    }
}

/// G2P of [`FlipUpdate::ParticleGs4`](crate::config::FlipUpdate::ParticleGs4): the FLIP part
/// is GS4-II applied to the particle ODE v̇ₚ = Σᵢ w̃ᵢₚ(fᵢ/mᵢ + g) itself, with the particle
/// acceleration aₚ as its rate:
/// Δaₚ = (Σ w̃ (fᵢ/mᵢ + g) − aₚ)/W₁Λ₆, vₚⁿ⁺¹ = vₚ + λ₄Δt aₚ + λ₅Δt Δaₚ, aₚⁿ⁺¹ = aₚ + Δaₚ.
/// Since fᵢ/mᵢ + g = aᵢⁿ + W₁Λ₆Δaᵢ, this is the [`g2p_stencil`] update plus a correction with
/// dₚ = aₚ − Σ w̃ aᵢⁿ (the part of aₚ the grid update did not see):
/// v_F += (λ₄ − λ₅/W₁Λ₆)Δt dₚ, a_F −= dₚ/W₁Λ₆ (collision changes enter through the grid
/// increments as in [`g2p_stencil`]). dₚ decays by 1 − 1/W₁Λ₆ per step (1/7 for (0.5, 0)),
/// which is what the §2.12 form lacks; and the GS4 predictor x̃, ṽ = P2G(vₚ + W₁Λ₄Δt aₚ) then
/// uses the rate of the very ODE being integrated, which keeps the step second order in time
/// with pure FLIP (`tests/it/integrators.rs`).
#[inline(always)]
pub fn g2p_stencil_particle_gs4(
    grid: &GridLayout,
    nodes: &[GridNode],
    st: &Stencil,
    x: Vec3,
    v: Vec3,
    a: Vec3,
    c: &StepCoefficients,
) -> G2pResult {
    let [v_pic, a_pic, v_old, a_old] = gather_node_fields(grid, nodes, st);
    let d = a - a_old;
    let inv_b = 1.0 / c.w1l6;
    let v_flip = v + (v_pic - v_old) + ((c.l4 - c.l5 * inv_b) * c.dt) * d;
    let a_flip = a + (a_pic - a_old) - inv_b * d;
    blend_flip(x, v, [v_pic, a_pic], [v_flip, a_flip], v_old, c)
}

/// Grid displacement gradient at the predicted configuration,
/// G̃ = Δt/2 Σᵢ (vᵢⁿ + vᵢⁿ⁺¹) ⊗ ∇w̃ᵢₚ (§2.13, for Fⁿ⁺¹ = Fⁿ + G̃F̃, choice D7).
#[inline(always)]
pub fn displacement_gradient(
    grid: &GridLayout,
    nodes: &[GridNode],
    x_tilde: Vec3,
    c: &StepCoefficients,
) -> Mat3 {
    displacement_gradient_stencil(grid, nodes, &Stencil::new(grid, x_tilde), c)
}

/// [`displacement_gradient`] with precomputed weights, in row form ([`Stencil::for_each_row`]).
#[inline(always)]
pub fn displacement_gradient_stencil(
    grid: &GridLayout,
    nodes: &[GridNode],
    st: &Stencil,
    c: &StepCoefficients,
) -> Mat3 {
    let half_dt = 0.5 * c.dt;
    let z = st.z_factors();
    let mut g = [Vec3A::ZERO; 3];
    st.for_each_row(grid, |idx, r| {
        let u =
            [0, 1, 2].map(|k| half_dt * (nodes[idx + k].velocity + nodes[idx + k].new_velocity));
        add_row_gradient(&mut g, &z, r, u);
    });
    Mat3::from(Mat3A::from_cols(g[0], g[1], g[2]))
}

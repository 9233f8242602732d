//! The ECS systems of [`super::ThermalPlugin`] (ALGORITHM §2.3 S1, S3, S12, S13; §3.3–3.4).
//!
//! The thermal lattice is block-sparse ([`BlockLattice`], 4³ nodes per block): it holds the
//! blocks of the MPM nodes touched by the stencils of heated particles, each stencil widened
//! by one node on every side (so that Dirichlet neighbours of Interior nodes are in it) and
//! clipped to the grid's node box. Nodes are numbered from [`ThermalGrid::origin`], the lowest
//! widened stencil node; memory and every pass over nodes scale with the allocated blocks,
//! not with the box around the heated particles (two melting bodies far apart cost what the
//! two bodies cost). Its fields live in [`ThermalGrid`], not in [`MpmGrid`]. The scatter uses
//! the slab-coloured [`ScatterPlan`] of the momentum P2G and the solve is serial, so the
//! result does not depend on the thread count.
use bevy_ecs::prelude::*;
use glam::IVec3;

use super::components::{FluxDivergence, PredictedTemperature, Temperature};
use super::enthalpy::MeltingBand;
use super::multigrid::{BLOCK_CELLS, BlockLattice, NodeClass};
use super::solve::{HeatCoefficients, HeatHalo, HeatNodes, HeatSolver};
use super::{PrescribedTemperature, ThermalConfig, ThermalMaterial};
use crate::collision::{Collider, ColliderPose};
use crate::components::{
    CauchyStress, Mass, Particle, ParticleStencil, PredictedDensity, VelocityGradient,
};
use crate::config::MpmConfig;
use crate::distributed::{RankReduction, Ranks, f64_at, push_f64s};
use crate::failure::{FailureCollector, FailureReport};
use crate::grid::{GridLayout, MpmGrid};
use crate::gs4::Gs4Params;
use crate::krylov::Reduction;
use crate::material::MaterialId;
use crate::math::Real;
use crate::scatter::{ScatterPlan, SharedMut};
use crate::step::schedule::{Gs4Constants, StepContext};

/// Thermal grid fields and solver scratch (reused across steps; no allocation once sized).
#[derive(Resource, Default, Debug)]
pub struct ThermalGrid {
    /// The heat solver (operator with this step's node classes, multigrid, CG scratch).
    pub solver: HeatSolver,
    /// Nodal T, Ṫ, d, ḋ, Q at tⁿ after P2G; at tⁿ⁺¹ with the increments after the solve.
    pub nodes: HeatNodes,
    /// Thermal node mass m̃ᵢ (heated particles only) \[kg\].
    pub mass: Vec<f64>,
    /// Mass-weighted surface heat source \[K/s\].
    pub surface_source: Vec<f64>,
    /// Mass-weighted particle enthalpy H(Tₚ) at tⁿ (latent heat only, [`super::enthalpy`]).
    pub enthalpy: Vec<f64>,
    /// Scratch of the mechanical heating scatter: Σ w̃ m s Φ per node.
    heating: Vec<f64>,
    /// MPM node coordinates of the lattice's node (0, 0, 0).
    pub origin: IVec3,
    /// Extent of the box of lattice nodes (per axis): every allocated node c has
    /// 0 ≤ c < core.
    pub core: [usize; 3],
    /// The allocated blocks (the storage of every nodal vector).
    pub lattice: BlockLattice,
    /// Whether this step has a thermal lattice (heated particles exist and the solve did
    /// not fail).
    pub active: bool,
    /// Nodes with m̃ᵢ ≤ this are not Interior \[kg\].
    pub mass_epsilon: f64,
    /// The coefficients of the current step.
    pub coefficients: Option<HeatCoefficients>,
    items: Vec<ScatterItem>,
    /// The items' particle stencils (distributed runs only: what the items travel as).
    item_stencils: Vec<ParticleStencil>,
    accumulator: Vec<[f64; 8]>,
    plan: ScatterPlan,
    /// Scratch of the transfer-consistent predictor: the nodal rates R⁰ at the predictors.
    rates: Vec<[f64; 2]>,
    /// A split solve's halo (distributed runs): per side (lower, upper neighbour), the storage
    /// indices of this rank's ghost nodes, and of its own nodes that neighbour holds as ghosts,
    /// in the order the two ranks agreed.
    halo_recv: [Vec<u32>; 2],
    halo_send: [Vec<u32>; 2],
}

/// One heated particle of the thermal P2G: weights (at the predicted position) and mass-weighted
/// values (m, mT, mṪ, mQ, md — or mH(T) with latent heat, where d = 0 —, mḋ, mQ_surface,
/// m L/c); the last four only matter for τ > 0, a surface source or latent heat, and are
/// scattered only then.
#[derive(Clone, Copy, Debug)]
struct ScatterItem {
    stencil: crate::kernels::Stencil,
    values: [f64; 8],
}

/// Scatters the first `N` values of every item (module docs: deterministic, slab-coloured).
fn scatter_items<const N: usize>(
    plan: &ScatterPlan,
    items: &[ScatterItem],
    accumulator: &mut [[f64; 8]],
    origin: IVec3,
    lattice: &BlockLattice,
) {
    debug_assert_eq!(accumulator.len(), lattice.len());
    let acc = SharedMut(accumulator.as_mut_ptr());
    plan.run(|p| {
        let it = &items[p];
        let nodes = lattice.stencil_indices((it.stencil.base - origin).to_array());
        for i in 0..3 {
            for j in 0..3 {
                let wxy = it.stencil.w[0][i] * it.stencil.w[1][j];
                for k in 0..3 {
                    let w = (wxy * it.stencil.w[2][k]) as f64;
                    let idx = nodes[(i * 3 + j) * 3 + k] as usize;
                    // SAFETY: `ScatterPlan::run` never runs two particles whose stencils
                    // share a grid node concurrently; allocated lattice nodes map one-to-one
                    // to grid nodes, every heated particle's stencil lies in allocated blocks
                    // (they were marked from it), and `stencil_indices` returns indices below
                    // `lattice.len()` = `accumulator.len()`.
                    let node = unsafe { &mut *acc.get().add(idx) };
                    for (a, v) in node[..N].iter_mut().zip(&it.values[..N]) {
                        *a += w * v;
                    }
                }
            }
        }
    });
}

impl ThermalGrid {
    /// Storage index of the node with lattice coordinates `c` (MPM node − [`Self::origin`];
    /// a dummy-block index, whose values are zero, for a node outside the allocated blocks).
    #[inline(always)]
    pub fn index(&self, c: IVec3) -> usize {
        self.lattice.index(c.to_array())
    }

    /// Storage indices of the 27 nodes of the stencil with MPM base node `base`, at
    /// `(i·3 + j)·3 + k` ([`BlockLattice::stencil_indices`]).
    #[inline(always)]
    pub fn stencil_indices(&self, base: IVec3) -> [u32; 27] {
        self.lattice
            .stencil_indices((base - self.origin).to_array())
    }
}

/// Solver statistics (cumulative and of the last solve).
#[derive(Resource, Clone, Copy, Debug, Default, PartialEq)]
pub struct ThermalStats {
    /// Heat solves run (including the start-up rate evaluation).
    pub solves: u64,
    /// CG iterations of the last solve.
    pub last_iterations: usize,
    /// Largest CG iteration count so far.
    pub max_iterations: usize,
    /// Sum of CG iterations.
    pub total_iterations: u64,
    /// Unknowns (Interior nodes) of the last solve.
    pub last_unknowns: usize,
    /// Multigrid levels of the last solve.
    pub last_levels: usize,
    /// Final relative residual of the last solve.
    pub last_rel_residual: f64,
}

/// The GS4 parameters of the heat equation: [`ThermalConfig::gs4`] or the mechanics'.
pub fn heat_gs4(config: &ThermalConfig, mechanics: &Gs4Constants) -> Gs4Params {
    config
        .gs4
        .and_then(|(ri, rs)| Gs4Params::new(ri, rs).ok())
        .unwrap_or(mechanics.params)
}

fn step_coefficients(
    config: &ThermalConfig,
    gs4: &Gs4Constants,
    ctx: &StepContext,
) -> Option<HeatCoefficients> {
    let heat = config.heat_parameters()?;
    Some(HeatCoefficients::new(
        &heat_gs4(config, gs4),
        ctx.dt,
        ctx.rate_evaluation,
        heat,
    ))
}

/// Inserts the thermal components on particles of heated materials that do not have them yet
/// (scene particles at the first step, emitted particles later). A [`Temperature`] already
/// present (e.g. T_inj set by an emitter) is kept; otherwise
/// [`ThermalMaterial::initial_temperature`] is used. Also called by
/// [`crate::scene::Scene::apply`] so that frame 0 already has temperatures. Does nothing
/// without a [`ThermalConfig`].
pub fn attach_thermal_state(world: &mut World) {
    let Some(config) = world.get_resource::<ThermalConfig>() else {
        return;
    };
    let materials: Vec<(MaterialId, ThermalMaterial)> = config.materials.clone();
    let mut q = world.query_filtered::<(Entity, &MaterialId, Option<&Temperature>), (
        With<Particle>,
        Without<PredictedTemperature>,
    )>();
    let todo: Vec<(Entity, Temperature)> = q
        .iter(world)
        .filter_map(|(e, id, t)| {
            let m = materials.iter().find(|(mid, _)| mid == id)?.1;
            let t = t.copied().unwrap_or(Temperature {
                value: m.initial_temperature,
                rate: 0.0,
            });
            Some((e, t))
        })
        .collect();
    for (e, t) in todo {
        let mut em = world.entity_mut(e);
        em.insert((t, PredictedTemperature(t.value)));
        if !em.contains::<FluxDivergence>() {
            em.insert(FluxDivergence::default());
        }
    }
}

/// S1 (§2.4, §3.4): T̂ₚ = Tₚ + W₁Λ₄Δt Ṫₚ, read by the phase index and temperature-dependent
/// viscosities of this step.
pub fn predict_temperature(
    ctx: Res<StepContext>,
    config: Res<ThermalConfig>,
    gs4: Res<Gs4Constants>,
    mut q: Query<(&Temperature, &mut PredictedTemperature), With<Particle>>,
) {
    let Some(c) = step_coefficients(&config, &gs4, &ctx) else {
        return;
    };
    let s = c.w1l4_dt as Real;
    q.par_iter_mut().for_each(|(t, mut th)| {
        th.0 = t.value + s * t.rate;
    });
}

/// What the thermal P2G reads of a particle.
type HeatedParticle = (
    &'static ParticleStencil,
    &'static Mass,
    &'static MaterialId,
    &'static Temperature,
    &'static FluxDivergence,
);

/// S3 for heat (§2.5, §3.4): mass-weighted T, Ṫ, d, ḋ and the material sources of heated
/// particles on the thermal lattice, with the momentum weights ([`ParticleStencil`]). An
/// invalid [`ThermalConfig`] stops the run with a diagnostic instead.
pub fn thermal_particle_to_grid(
    config: Res<ThermalConfig>,
    grid: Res<MpmGrid>,
    failures: Res<FailureCollector>,
    mut tg: ResMut<ThermalGrid>,
    q: Query<HeatedParticle, With<Particle>>,
    ranks: Option<Res<Ranks>>,
) {
    let tg = &mut *tg;
    tg.active = false;
    tg.coefficients = None;
    // A configuration built in code is checked here (scene files are validated at load).
    if let Err((field, reason)) = config.validate() {
        failures.record(FailureReport::global(
            "thermal configuration",
            f64::NAN,
            format!("ThermalConfig.{field} {reason}"),
        ));
        return;
    }
    // Gather the heated particles (copies, in query order, into reused storage).
    tg.items.clear();
    tg.item_stencils.clear();
    let ranks = ranks.as_deref().filter(|r| r.size() > 1);
    let band = config.melting_band().map(MeltingBand::new);
    let layout = grid.layout;
    for (pst, m, id, t, d) in &q {
        let Some(mat) = config.material(*id) else {
            continue;
        };
        let st = pst.stencil(&layout);
        if ranks.is_some() {
            tg.item_stencils.push(*pst);
        }
        let m = m.0 as f64;
        tg.items.push(ScatterItem {
            stencil: st,
            values: [
                m,
                m * t.value as f64,
                m * t.rate as f64,
                m * mat.volumetric_source as f64,
                // With latent heat (Fourier only, validated) d = 0: the slot carries H(Tₚ).
                m * band.map_or(d.value as f64, |b| {
                    b.enthalpy(t.value as f64, mat.latent_heat as f64)
                }),
                m * d.rate as f64,
                m * mat.surface_source as f64,
                m * mat.latent_heat as f64,
            ],
        });
    }
    if let Some(ranks) = ranks {
        let local = std::mem::take(&mut tg.item_stencils);
        exchange_items(ranks, &layout, &local, &mut tg.items);
        tg.item_stencils = local;
    }
    let mut bmin = IVec3::MAX;
    let mut bmax = IVec3::MIN;
    let mut m_min = f64::INFINITY;
    for it in &tg.items {
        bmin = bmin.min(it.stencil.base);
        bmax = bmax.max(it.stencil.base);
        m_min = m_min.min(it.values[0]);
    }
    // Split over ranks, every rank takes part in the solve if any has heated particles, with
    // the same mass threshold.
    if let Some(ranks) = ranks {
        m_min = -ranks.max(&[-m_min])[0];
    }
    if !m_min.is_finite() {
        return;
    }
    if tg.items.is_empty() {
        // A rank without heated particles near its columns: an empty lattice.
        bmin = layout.lo + IVec3::ONE;
        bmax = bmin;
    }
    let lo = (bmin - IVec3::ONE).max(layout.lo);
    let hi = (bmax + IVec3::splat(3)).min(layout.lo + layout.dims - IVec3::ONE);
    tg.origin = lo;
    tg.core = (hi - lo + IVec3::ONE).to_array().map(|v| v as usize);
    tg.mass_epsilon = 1e-10 * m_min;
    // The blocks of every stencil widened by one node, clipped to [lo, hi].
    let top = hi - lo;
    tg.lattice.begin([0; 3], top.to_array());
    let mut last = IVec3::MIN;
    for it in &tg.items {
        let base = it.stencil.base;
        if base == last {
            continue;
        }
        last = base;
        let c0 = (base - lo - IVec3::ONE).max(IVec3::ZERO);
        let c1 = (base - lo + IVec3::splat(3)).min(top);
        tg.lattice.mark_cells(c0.to_array(), c1.to_array());
    }
    tg.lattice.finish();
    let n = tg.lattice.len();
    tg.accumulator.clear();
    tg.accumulator.resize(n, [0.0; 8]);
    // Deterministic parallel scatter: the slab-coloured plan of the momentum P2G
    // ([`crate::scatter`]) never runs two particles that share a node at the same time, and
    // every node receives its contributions in a fixed order, whatever the thread count.
    tg.plan
        .build_from_bases(&layout, tg.items.iter().map(|it| it.stencil.base));
    let full = config
        .heat_parameters()
        .is_some_and(|p| p.relaxation_time > 0.0)
        || config
            .materials
            .iter()
            .any(|(_, m)| m.surface_source != 0.0 || m.latent_heat > 0.0);
    let latent = config.melting_band().is_some();
    let ThermalGrid {
        plan,
        items,
        accumulator,
        origin,
        lattice,
        ..
    } = tg;
    if full {
        scatter_items::<8>(plan, items, accumulator, *origin, lattice);
    } else {
        scatter_items::<4>(plan, items, accumulator, *origin, lattice);
    }
    let eps = tg.mass_epsilon;
    tg.nodes.reset(n);
    tg.mass.clear();
    tg.mass.resize(n, 0.0);
    tg.surface_source.clear();
    tg.surface_source.resize(n, 0.0);
    // Mass-weighted L/c per node goes straight to the solver (empty without latent heat).
    tg.solver.latent.clear();
    tg.enthalpy.clear();
    if latent {
        tg.solver.latent.resize(n, 0.0);
        tg.enthalpy.resize(n, 0.0);
    }
    let nodes = &mut tg.nodes;
    for (i, a) in tg.accumulator.iter().enumerate() {
        let m = a[0];
        tg.mass[i] = m;
        if m > eps {
            let inv = 1.0 / m;
            nodes.temperature[i] = a[1] * inv;
            nodes.temperature_rate[i] = a[2] * inv;
            nodes.source[i] = a[3] * inv;
            nodes.flux_rate[i] = a[5] * inv;
            tg.surface_source[i] = a[6] * inv;
            if latent {
                tg.enthalpy[i] = a[4] * inv;
                tg.solver.latent[i] = a[7] * inv;
            } else {
                nodes.flux[i] = a[4] * inv;
            }
        }
    }
    tg.active = true;
}

/// Words of a gathered heated particle: its stencil (base, offset) and eight f64 values.
const ITEM_WORDS: usize = 6 + 16;

/// Words of a [`ParticleStencil`] (the base node and the offset's bits).
fn pack_stencil(st: &ParticleStencil, out: &mut Vec<u32>) {
    out.extend(st.base.to_array().map(|c| c as u32));
    out.extend(st.offset.to_array().map(Real::to_bits));
}

fn unpack_stencil(w: &[u32]) -> ParticleStencil {
    ParticleStencil {
        base: IVec3::new(w[0] as i32, w[1] as i32, w[2] as i32),
        offset: crate::math::Vec3::new(
            Real::from_bits(w[3]),
            Real::from_bits(w[4]),
            Real::from_bits(w[5]),
        ),
    }
}

/// Appends `words` (a particle's record, its stencil `st` first) to the message of each
/// neighbour rank that holds a node of the stencil ([`Ranks::holds_node`]): `send` = [to rank −
/// 1, to rank + 1].
fn send_to_holders(
    ranks: &Ranks,
    layout: &GridLayout,
    st: &ParticleStencil,
    words: &[u32],
    send: &mut [Vec<u32>; 2],
) {
    let rank = ranks.rank();
    let axis = ranks.axis();
    for (side, nb) in [rank.wrapping_sub(1), rank + 1].into_iter().enumerate() {
        if nb >= ranks.size() {
            continue;
        }
        let reaches = (0..3).any(|k| {
            let mut n = st.base;
            n[axis] += k;
            ranks.holds_node(nb, layout, n)
        });
        if reaches {
            send[side].extend_from_slice(words);
        }
    }
}

/// A distributed run (ALGORITHM §12): this rank's heated particles (`items`, whose particle
/// stencils are `local`) go to the neighbours that hold a node of their stencils, and theirs
/// come here, appended in rank order. Every node this rank holds (its own and its ghosts) then
/// has its complete sums.
fn exchange_items(
    ranks: &Ranks,
    layout: &GridLayout,
    local: &[ParticleStencil],
    items: &mut Vec<ScatterItem>,
) {
    let mut send = [Vec::new(), Vec::new()];
    let mut words = Vec::with_capacity(ITEM_WORDS);
    for (st, it) in local.iter().zip(items.iter()) {
        words.clear();
        pack_stencil(st, &mut words);
        push_f64s(&mut words, it.values);
        send_to_holders(ranks, layout, st, &words, &mut send);
    }
    let [lower, upper] = send;
    let (a, b) = ranks.neighbour_exchange(lower, upper);
    for w in a.chunks_exact(ITEM_WORDS).chain(b.chunks_exact(ITEM_WORDS)) {
        items.push(ScatterItem {
            stencil: unpack_stencil(w).stencil(layout),
            values: std::array::from_fn(|k| f64_at(&w[6..], k)),
        });
    }
}

/// The halo of a heat solve split over ranks ([`HeatHalo`]); one process without `ranks`.
struct RankHalo<'a> {
    ranks: Option<&'a Ranks>,
    send: &'a [Vec<u32>; 2],
    recv: &'a [Vec<u32>; 2],
}

impl Reduction for RankHalo<'_> {
    fn sum(&self, local: f64) -> f64 {
        RankReduction(self.ranks).sum(local)
    }

    fn max(&self, local: f64) -> f64 {
        RankReduction(self.ranks).max(local)
    }

    fn sums_and_max(&self, sums: [f64; 2], max: f64) -> ([f64; 2], f64) {
        RankReduction(self.ranks).sums_and_max(sums, max)
    }

    fn fuses(&self) -> bool {
        RankReduction(self.ranks).fuses()
    }
}

impl HeatHalo for RankHalo<'_> {
    fn split(&self) -> bool {
        self.ranks.is_some()
    }

    fn exchange(&self, scalars: &mut [&mut [f64]], pairs: &mut [&mut [[f64; 2]]]) {
        let Some(ranks) = self.ranks else {
            return;
        };
        let mut out = [Vec::new(), Vec::new()];
        for (msg, idx) in out.iter_mut().zip(self.send) {
            for f in scalars.iter() {
                push_f64s(msg, idx.iter().map(|&i| f[i as usize]));
            }
            for f in pairs.iter() {
                push_f64s(msg, idx.iter().flat_map(|&i| f[i as usize]));
            }
        }
        let [lower, upper] = out;
        let (a, b) = ranks.neighbour_exchange(lower, upper);
        for (msg, idx) in [a, b].iter().zip(self.recv) {
            let per = scalars.len() + 2 * pairs.len();
            assert_eq!(
                msg.len(),
                2 * per * idx.len(),
                "thermal halo: a neighbour sent another number of ghost values"
            );
            let mut k = 0;
            for f in scalars.iter_mut() {
                for &i in idx {
                    f[i as usize] = f64_at(msg, k);
                    k += 1;
                }
            }
            for f in pairs.iter_mut() {
                for &i in idx {
                    f[i as usize] = [f64_at(msg, k), f64_at(msg, k + 1)];
                    k += 2;
                }
            }
        }
    }
}

/// Agrees a split solve's halo with the neighbours (distributed runs): this rank's ghost nodes
/// on each side (held, not owned, allocated here), in storage order, go to that neighbour as
/// grid node coordinates; the neighbour's list, mapped to this rank's storage indices (a
/// dummy-block index, value zero, for a node not allocated here), is what this rank sends it.
fn agree_halo(
    ranks: &Ranks,
    layout: &GridLayout,
    origin: IVec3,
    lattice: &BlockLattice,
    recv: &mut [Vec<u32>; 2],
    send: &mut [Vec<u32>; 2],
) {
    let rank = ranks.rank();
    let axis = ranks.axis();
    let mut coords = [Vec::new(), Vec::new()];
    recv.iter_mut().for_each(Vec::clear);
    send.iter_mut().for_each(Vec::clear);
    for idx in BLOCK_CELLS..lattice.len() {
        let Some(c) = lattice.coords(idx) else {
            continue;
        };
        let node = origin + IVec3::from_array(c);
        if ranks.owns_node(layout, node) || !ranks.holds_node(rank, layout, node) {
            continue;
        }
        // Below this rank's columns: the lower neighbour's; above: the upper's.
        let mut probe = node;
        probe[axis] += 2;
        let side = usize::from(!ranks.owns_node(layout, probe));
        recv[side].push(idx as u32);
        coords[side].extend(node.to_array().map(|v| v as u32));
    }
    let [lower, upper] = coords;
    let (a, b) = ranks.neighbour_exchange(lower, upper);
    for (side, msg) in [a, b].iter().enumerate() {
        for w in msg.chunks_exact(3) {
            let node = IVec3::new(w[0] as i32, w[1] as i32, w[2] as i32);
            send[side].push(lattice.index((node - origin).to_array()) as u32);
        }
    }
}

/// S12 (§3.2–3.3, §3.5): node classes (Dirichlet inside prescribed-temperature walls and
/// colliders, Interior where m̃ᵢ > m_ε, else Exterior), sources, and the GS4 C-F solve.
/// A failed solve is recorded for the monitor (the run stops) and the particles keep their
/// temperatures.
///
/// **Transfer-consistent predictor (a deviation from §3.2, the heat analogue of the implicit
/// viscous solve's, [`crate::step::implicit::viscous::implicit_viscous_update`]).** The particle
/// update of [`thermal_grid_to_particle`] is GS4-II on the particle ODE Ṫₚ = Σ w̃ᵢₚ Rᵢ
/// (R the nodal rate of §3.1). Its implicit evaluation point, seen on the grid, is
/// P(T̃ₚ + aΔṪₚ) = T̃ + θ(PW R − Ṫ) with θ = a/b, P the mass-weighted P2G and W the G2P,
/// whereas the grid solve evaluates R at T̃ + θ(R − Ṫ): since PW ≠ I the two differ by
/// θ(I − PW)R = O(Δt), which made the particle temperatures only first order in time
/// (fitted 0.89 on `tests/it/heat.rs::heat_transfer_through_mpm_is_second_order_in_time`).
/// The predictors (T̃, d̃) therefore lose θD with D = (I − PW)R⁰, R⁰ the rates (Ṫ, ḋ) at the
/// unshifted predictors ([`super::solve::HeatSolver::predictor_rates`]); what remains,
/// θ(I − PW)(R − R⁰), is O(Δt²) (measured order 1.98, errors 20–70× smaller). The
/// correction is explicit in R⁰, so it runs only while θ·z_max ≤
/// [`crate::gs4::TRANSFER_CORRECTION_MAX_STIFFNESS`] (z_max = 12k/Δx², + 1/τ): beyond that
/// it would grow the stiff lattice modes (see there); larger steps take the uncorrected,
/// first-order, unconditionally stable update; [`super::HeatTransfer::consistent_predictor`]
/// turns it off. Cost: one Laplacian and one gather/scatter
/// round trip over the heated particles per step, with the P2G's slab plan (deterministic);
/// +18 % on the 1-thread step of `bunny_melting_1` (BENCHMARKS.md (g)).
#[allow(clippy::too_many_arguments)]
pub fn thermal_solve(
    ctx: Res<StepContext>,
    config: Res<ThermalConfig>,
    mpm: Res<MpmConfig>,
    gs4: Res<Gs4Constants>,
    grid: Res<MpmGrid>,
    mut tg: ResMut<ThermalGrid>,
    mut stats: ResMut<ThermalStats>,
    failures: Res<FailureCollector>,
    bodies: Query<(&Collider, &ColliderPose, &PrescribedTemperature)>,
    materials: Res<crate::material::Materials>,
    heated: Query<StressPower, (With<Particle>, With<Temperature>)>,
    ranks: Option<Res<Ranks>>,
) {
    if !tg.active {
        return;
    }
    let Some(coefficients) = step_coefficients(&config, &gs4, &ctx) else {
        tg.active = false;
        return;
    };
    let layout = grid.layout;
    let bodies: Vec<_> = bodies.iter().collect();
    let walls = config.walls;
    let tol = 1e-4 * layout.dx;
    let (dmin, dmax) = (mpm.domain_min, mpm.domain_max);
    let tg = &mut *tg;
    let ThermalGrid {
        solver,
        nodes,
        mass,
        surface_source,
        heating,
        origin,
        core,
        lattice,
        mass_epsilon,
        items,
        accumulator,
        plan,
        rates,
        halo_recv,
        halo_send,
        ..
    } = tg;
    let origin = *origin;
    let eps = *mass_epsilon;
    let ranks = ranks.as_deref().filter(|r| r.size() > 1);
    if let Some(ranks) = ranks {
        agree_halo(ranks, &layout, origin, lattice, halo_recv, halo_send);
    }
    // Split over ranks: this rank's own nodes are the unknowns, its neighbours' within reach
    // are ghosts, nodes beyond them (partial sums) are left out.
    let held = |node: IVec3| ranks.is_none_or(|r| r.holds_node(r.rank(), &layout, node));
    let owned = |node: IVec3| ranks.is_none_or(|r| r.owns_node(&layout, node));
    let prescribed = |node: IVec3| -> Option<Real> {
        let x = layout.node_position(node);
        for a in 0..3 {
            if let Some(t) = walls.face(a, false)
                && x[a] <= dmin[a] + tol
            {
                return Some(t);
            }
            if let Some(t) = walls.face(a, true)
                && x[a] >= dmax[a] - tol
            {
                return Some(t);
            }
        }
        for (c, pose, t) in &bodies {
            let local = pose.rotation.inverse() * (x - pose.translation);
            if c.shape.sdf(local).0 <= 0.0 {
                return Some(t.0);
            }
        }
        None
    };
    // Classes; Dirichlet nodes get T_D in `temperature` and zero rates.
    solver.prepare_on(lattice, *core, layout.dx as f64, |c, idx| {
        let node = origin + IVec3::new(c[0] as i32, c[1] as i32, c[2] as i32);
        if !held(node) {
            NodeClass::Exterior
        } else if let Some(t_d) = prescribed(node) {
            nodes.temperature[idx] = t_d as f64;
            nodes.temperature_rate[idx] = 0.0;
            nodes.flux[idx] = 0.0;
            nodes.flux_rate[idx] = 0.0;
            NodeClass::Dirichlet
        } else if mass[idx] > eps {
            if owned(node) {
                NodeClass::Interior
            } else {
                NodeClass::Ghost
            }
        } else {
            NodeClass::Exterior
        }
    });
    // Surface source and ambient exchange on Interior nodes with Exterior faces (§3.3).
    let dx = layout.dx as f64;
    for &i in solver.operator.interior() {
        let i = i as usize;
        let faces = solver.operator.exterior_faces(i);
        if faces == 0 {
            continue;
        }
        nodes.source[i] += surface_source[i];
        if let Some(a) = config.ambient {
            let t_tilde = nodes.temperature[i] + coefficients.w1l4_dt * nodes.temperature_rate[i];
            nodes.source[i] -=
                a.coefficient as f64 * faces as f64 * (t_tilde - a.temperature as f64) / dx;
        }
    }
    let halo = RankHalo {
        ranks,
        send: halo_send,
        recv: halo_recv,
    };
    mechanical_heating(
        &config, &materials, &heated, &layout, solver, nodes, mass, heating, origin, lattice, ranks,
    );
    // Latent heat (§3.1): the solver forms Cᵢ = 1 + (L/c)ᵢ δ_ε(T̃ᵢ − T_m) from the nodal L/c
    // of the P2G and this band.
    if let Some(band) = config.melting_band() {
        solver.melting_band = band;
    }
    // Transfer-consistent predictor (see the docs): D = (I − PW)R⁰ on the Interior nodes.
    solver.predictor_shift.clear();
    let h = layout.dx as f64;
    let heat = coefficients.heat;
    let z_max = 12.0 * heat.diffusivity / (h * h)
        + if heat.relaxation_time > 0.0 {
            1.0 / heat.relaxation_time
        } else {
            0.0
        };
    let theta = coefficients.a / coefficients.b;
    if config.transfer.consistent_predictor
        && !ctx.rate_evaluation
        && coefficients.a > 0.0
        && theta * z_max <= crate::gs4::TRANSFER_CORRECTION_MAX_STIFFNESS
    {
        transfer_consistent_shift(
            solver,
            &coefficients,
            nodes,
            rates,
            accumulator,
            plan,
            items,
            mass,
            origin,
            lattice,
            &halo,
        );
    }
    match solver.advance_with(&config.solver, &coefficients, nodes, &halo) {
        Ok(info) => {
            stats.solves += 1;
            stats.last_iterations = info.cg.iterations;
            stats.max_iterations = stats.max_iterations.max(info.cg.iterations);
            stats.total_iterations += info.cg.iterations as u64;
            stats.last_unknowns = info.unknowns;
            stats.last_levels = info.levels;
            stats.last_rel_residual = info.cg.rel_residual;
            tg.coefficients = Some(coefficients);
        }
        Err(e) => {
            tg.active = false;
            failures.record(FailureReport::global(
                "heat solve",
                f64::NAN,
                format!(
                    "{e}; fix: raise thermal solver.cg.max_iters or rel_tol, or check the \
                     thermal parameters"
                ),
            ));
        }
    }
}

/// What the mechanical heating reads of a heated particle.
type StressPower = (
    &'static ParticleStencil,
    &'static Mass,
    &'static MaterialId,
    &'static CauchyStress,
    &'static VelocityGradient,
    &'static PredictedDensity,
);

/// Φ = (σ + pI) : D with D = ½(L + Lᵀ) (choice D10: the stress power without the reversible
/// pressure work −p tr D) \[W/m³\], in f64.
pub fn stress_power(sigma: &glam::Mat3, p: f64, l: &glam::Mat3) -> f64 {
    let mut phi = 0.0;
    for a in 0..3 {
        for b in 0..3 {
            let d = 0.5 * (l.col(b)[a] as f64 + l.col(a)[b] as f64);
            let s = sigma.col(b)[a] as f64 + if a == b { p } else { 0.0 };
            phi += s * d;
        }
    }
    phi
}

/// A particle temperature whose magnitude exceeds this multiple of
/// [`ThermalConfig::temperature_scale`] is a blow-up: the heat solve is unconditionally stable
/// and bounded by the maximum principle without sources, so only an instability (or an
/// absurd heat source) gets there; the check stops the run long before f32 overflows (a
/// finite runaway would otherwise pass as healthy output).
pub const BLOWUP_TEMPERATURE_FACTOR: f64 = 1e6;

/// S13 for heat (§2.12, §3.4): the particle update of T, Ṫ, d, ḋ.
///
/// **Transfer-consistent FLIP (a deviation from §3.4's "exactly as §2.12").** The FLIP part
/// is GS4-II applied to the particle's own rate equation, as
/// [`crate::kernels::g2p_stencil_particle_gs4`] does for the velocity: with
/// b = W₁Λ₆, the grid target rate Σ w̃ (Ṫᵢⁿ + bΔṪᵢ) and the particle rate Ṫₚ,
/// ΔṪₚ = Σ w̃ ΔṪᵢ − eₚ/b with eₚ = Ṫₚ − Σ w̃ Ṫᵢⁿ, then
/// T_F = Tₚ + λ₄Δt Ṫₚ + λ₅Δt ΔṪₚ and Ṫ_F = Ṫₚ + ΔṪₚ (the same for d, ḋ; Dirichlet and
/// Exterior nodes carry zero rates, so a prescribed temperature reaches the particles through
/// the increments of the Interior nodes next to it, and through the PIC part). The §2.12 form (eₚ ignored) lets the part of Ṫₚ the grid
/// cannot see persist forever and be integrated into Tₚ (a pure-FLIP run drifted to
/// T ∈ [−685, 768] in bunny melting 1 with T ∈ [0, 1] physically); here it decays by
/// 1 − 1/b per step. The PIC part T_P = Σ w̃ Tᵢⁿ⁺¹, Ṫ_P = Σ w̃ Ṫᵢⁿ⁺¹ is blended with
/// [`super::HeatTransfer::flip`] (default 0.99; PIC transfers of a scalar are numerical
/// diffusion, see there, but pure FLIP keeps the sub-cell differences between particles the
/// grid cannot see, e.g. the initial jump at a hot wall, forever; H5 in `tests/it/heat.rs`). In the start-up rate evaluation (§2.14) the values are
/// kept and the rates are PIC. A non-finite result is reported and not written.
pub fn thermal_grid_to_particle(
    ctx: Res<StepContext>,
    config: Res<ThermalConfig>,
    tg: Res<ThermalGrid>,
    grid: Res<MpmGrid>,
    failures: Res<FailureCollector>,
    mut q: Query<
        (
            Entity,
            &ParticleStencil,
            &MaterialId,
            &mut Temperature,
            &mut FluxDivergence,
        ),
        With<Particle>,
    >,
) {
    if !tg.active {
        return;
    }
    let Some(c) = tg.coefficients else {
        return;
    };
    // α_T over the step's interval (`integrator.flip_interval`, D19): the PIC smoothing of T
    // acts per unit time, as the velocity's does.
    let alpha = ctx.flip_per_step(config.transfer.flip);
    let startup = ctx.rate_evaluation;
    let inv_b = 1.0 / c.b;
    let scale = config.temperature_scale();
    let t_limit = BLOWUP_TEMPERATURE_FACTOR * scale;
    let tg = &*tg;
    let nodes = &tg.nodes;
    // Latent heat: the capacity of the solve and the band (module docs of `super::enthalpy`).
    let capacity = tg.solver.capacity();
    let band = config
        .melting_band()
        .filter(|_| capacity.len() == nodes.temperature.len() && !tg.enthalpy.is_empty())
        .map(MeltingBand::new);
    let classes = tg.solver.operator.classes();
    let layout = grid.layout;
    q.par_iter_mut().for_each(|(e, st, id, mut t, mut d)| {
        let st = st.stencil(&layout);
        // Σ w̃ of: Tⁿ⁺¹, Ṫⁿ⁺¹, ΔṪ, dⁿ⁺¹, ḋⁿ⁺¹, Δḋ.
        let mut s = [0.0f64; 6];
        // With latent heat, Σ w̃ of: Cᵢ, Hᵢⁿ⁺¹ (below).
        let mut sh = [0.0f64; 2];
        let latent = band.map(|b| {
            let l = config.material(*id).map_or(0.0, |m| m.latent_heat as f64);
            (b, l)
        });
        let stencil_nodes = tg.stencil_indices(st.base);
        for i in 0..3 {
            for j in 0..3 {
                let wxy = st.w[0][i] * st.w[1][j];
                for k in 0..3 {
                    let w = (wxy * st.w[2][k]) as f64;
                    let idx = stencil_nodes[(i * 3 + j) * 3 + k] as usize;
                    s[0] += w * nodes.temperature[idx];
                    s[1] += w * nodes.temperature_rate[idx];
                    s[2] += w * nodes.temperature_increment[idx];
                    s[3] += w * nodes.flux[idx];
                    s[4] += w * nodes.flux_rate[idx];
                    s[5] += w * nodes.flux_increment[idx];
                    if let Some((b, l)) = latent {
                        // Hᵢⁿ⁺¹ = Hᵢⁿ + Cᵢ(Tᵢⁿ⁺¹ − Tᵢⁿ) on Interior nodes (the heat the solve
                        // moved there); elsewhere H(Tᵢⁿ⁺¹) of this particle's material.
                        let h = if classes[idx] == NodeClass::Interior {
                            let inc = nodes.temperature_increment[idx];
                            let rate_n = nodes.temperature_rate[idx] - inc;
                            let dt_node = c.l4_dt * rate_n + c.l5_dt * inc;
                            tg.enthalpy[idx] + capacity[idx] * dt_node
                        } else {
                            b.enthalpy(nodes.temperature[idx], l)
                        };
                        sh[0] += w * capacity[idx];
                        sh[1] += w * h;
                    }
                }
            }
        }
        // The FLIP value and rate (T_F, Ṫ_F) of the GS4-II particle update.
        let flip = |value: f64, rate: f64, pic_rate: f64, inc: f64| {
            // eₚ = Ṫₚ − Σ w̃ Ṫᵢⁿ with Ṫᵢⁿ = Ṫᵢⁿ⁺¹ − ΔṪᵢ.
            let rate_inc = inc - (rate - (pic_rate - inc)) * inv_b;
            (value + c.l4_dt * rate + c.l5_dt * rate_inc, rate + rate_inc)
        };
        // (T_F, Ṫ_F) and the blend with the PIC part (values kept, rates PIC in the start-up).
        let update = |value: f64, rate: f64, pic: f64, pic_rate: f64, inc: f64| {
            if startup {
                return ((value, pic_rate), value);
            }
            let (v_f, r_f) = flip(value, rate, pic_rate, inc);
            (
                (
                    pic + alpha * (v_f - pic),
                    pic_rate + alpha * (r_f - pic_rate),
                ),
                v_f,
            )
        };
        let ((mut t_new, tr_new), t_flip) = update(t.value as f64, t.rate as f64, s[0], s[1], s[2]);
        if let (Some((b, l)), false) = (latent, startup) {
            // The same blend of the same increments, in enthalpy: the FLIP part adds the heat
            // C̄ (T_F − Tₚ) to H(Tₚ) (C̄ = Σ w̃ Cᵢ, the capacity the solve used), the PIC part
            // is Σ w̃ Hᵢⁿ⁺¹, and T follows from H. A node that crossed the band inside the
            // step (its C at the predictor missing the band) so no longer carries the particle
            // across it without paying L. The rate stays the grid's temperature rate
            // (converting it to C̄Ṫ/C(T) amplified it up to L·δ_ε(0) times where a particle
            // had just left the band, and the front ran away).
            let tp = t.value as f64;
            let h_flip = b.enthalpy(tp, l) + sh[0] * (t_flip - tp);
            let h_new = sh[1] + alpha * (h_flip - sh[1]);
            t_new = b.temperature(h_new, l, t_new);
        }
        let ((d_new, dr_new), _) = update(d.value as f64, d.rate as f64, s[3], s[4], s[5]);
        let out = [t_new, tr_new, d_new, dr_new].map(|v| v as Real);
        if let Some(bad) = out.iter().find(|v| !v.is_finite()) {
            failures.record(FailureReport::particle(
                e,
                "temperature",
                *bad as f64,
                "non-finite temperature or flux after the heat G2P",
            ));
            return;
        }
        if out[0].abs() as f64 > t_limit {
            failures.record(FailureReport::particle(
                e,
                "temperature",
                out[0] as f64,
                &format!(
                    "blow-up: |T| exceeds 10⁶ × the run's temperature scale {scale} (initial, \
                     melting, wall and ambient temperatures); reduce Δt, or check heat sources \
                     and the ambient exchange coefficient (explicit: stable for \
                     h·faces·Δt/Δx ≲ 1)"
                ),
            ));
            return;
        }
        *t = Temperature {
            value: out[0],
            rate: out[1],
        };
        *d = FluxDivergence {
            value: out[2],
            rate: out[3],
        };
    });
}

/// Mechanical heating (D10): Q += Σ w̃ m s Φ / m̃ᵢ on the Interior nodes, summed in query order
/// (serial, deterministic); nothing unless a heated material has `mechanical_heating > 0`. In a
/// distributed run the neighbours' sources that reach this rank's nodes follow, in rank order
/// (as the items of [`exchange_items`]).
#[allow(clippy::too_many_arguments)]
fn mechanical_heating(
    config: &ThermalConfig,
    materials: &crate::material::Materials,
    heated: &Query<StressPower, (With<Particle>, With<Temperature>)>,
    layout: &GridLayout,
    solver: &HeatSolver,
    nodes: &mut HeatNodes,
    mass: &[f64],
    heating: &mut Vec<f64>,
    origin: IVec3,
    lattice: &BlockLattice,
    ranks: Option<&Ranks>,
) {
    if !config
        .materials
        .iter()
        .any(|(_, m)| m.mechanical_heating > 0.0)
    {
        return;
    }
    let acc = heating;
    acc.clear();
    acc.resize(nodes.source.len(), 0.0);
    let mut add = |st: &ParticleStencil, q: f64| {
        let st = st.stencil(layout);
        let stencil_nodes = lattice.stencil_indices((st.base - origin).to_array());
        for i in 0..3 {
            for j in 0..3 {
                let wxy = st.w[0][i] * st.w[1][j];
                for k in 0..3 {
                    let w = (wxy * st.w[2][k]) as f64;
                    acc[stencil_nodes[(i * 3 + j) * 3 + k] as usize] += w * q;
                }
            }
        }
    };
    // A distributed run's sources (stencil and q per particle) for the neighbours holding
    // their nodes, exchanged below.
    let mut send = [Vec::new(), Vec::new()];
    let mut words = Vec::with_capacity(8);
    for (st, m, id, sigma, l, rho) in heated {
        let Some(scale) = config.material(*id).map(|t| t.mechanical_heating as f64) else {
            continue;
        };
        if scale == 0.0 {
            continue;
        }
        let p = materials.get(*id).pressure(rho.value) as f64;
        let phi = stress_power(&sigma.0, p, &l.0);
        let q = m.0 as f64 * scale * phi;
        add(st, q);
        if let Some(ranks) = ranks {
            words.clear();
            pack_stencil(st, &mut words);
            push_f64s(&mut words, [q]);
            send_to_holders(ranks, layout, st, &words, &mut send);
        }
    }
    if let Some(ranks) = ranks {
        let [lower, upper] = send;
        let (a, b) = ranks.neighbour_exchange(lower, upper);
        for w in a.chunks_exact(8).chain(b.chunks_exact(8)) {
            add(&unpack_stencil(w), f64_at(&w[6..], 0));
        }
    }
    for &i in solver.operator.interior() {
        let i = i as usize;
        nodes.source[i] += acc[i] / mass[i];
    }
}

/// The transfer-consistent predictor shift D = (I − PW)R⁰ on the Interior nodes (see the
/// module docs): R⁰ from the solver, gathered to the particles and scattered back with their
/// masses (P W R⁰), into `solver.predictor_shift`.
#[allow(clippy::too_many_arguments)]
fn transfer_consistent_shift(
    solver: &mut HeatSolver,
    coefficients: &HeatCoefficients,
    nodes: &HeatNodes,
    rates: &mut Vec<[f64; 2]>,
    accumulator: &mut [[f64; 8]],
    plan: &ScatterPlan,
    items: &[ScatterItem],
    mass: &[f64],
    origin: IVec3,
    lattice: &BlockLattice,
    halo: &RankHalo<'_>,
) {
    solver.predictor_rates_with(coefficients, nodes, rates, halo);
    accumulator.iter_mut().for_each(|a| *a = [0.0; 8]);
    let acc = SharedMut(accumulator.as_mut_ptr());
    let r0: &[[f64; 2]] = rates;
    plan.run(|p| {
        let it = &items[p];
        let stencil_nodes = lattice.stencil_indices((it.stencil.base - origin).to_array());
        let mut weights = [(0usize, 0.0f64); 27];
        let mut g = [0.0f64; 2];
        for i in 0..3 {
            for j in 0..3 {
                let wxy = it.stencil.w[0][i] * it.stencil.w[1][j];
                for k in 0..3 {
                    let w = (wxy * it.stencil.w[2][k]) as f64;
                    let idx = stencil_nodes[(i * 3 + j) * 3 + k] as usize;
                    weights[(i * 3 + j) * 3 + k] = (idx, w);
                    g[0] += w * r0[idx][0];
                    g[1] += w * r0[idx][1];
                }
            }
        }
        let m = it.values[0];
        for (idx, w) in weights {
            // SAFETY: as in `scatter_items` (same plan, items and lattice).
            let node = unsafe { &mut *acc.get().add(idx) };
            node[0] += w * m * g[0];
            node[1] += w * m * g[1];
        }
    });
    solver.predictor_shift.resize(rates.len(), [0.0; 2]);
    for &i in solver.operator.interior() {
        let i = i as usize;
        let inv = 1.0 / mass[i];
        solver.predictor_shift[i] = [
            rates[i][0] - accumulator[i][0] * inv,
            rates[i][1] - accumulator[i][1] * inv,
        ];
    }
}

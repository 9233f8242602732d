//! The GS4-1 semi-implicit C-F heat update on grid nodes (ALGORITHM §3.1–3.3), independent
//! of the ECS: node classes and values in, values at t_{n+1} and the rate increments out.
//!
//! With a = W₂Λ₅Δt, b = W₁Λ₆, D = bτ + a and β = a k (F_T τ b + a)/D (§3.2):
//!
//! * predictors T̃ᵢ = Tᵢ + W₁Λ₄Δt Ṫᵢ, d̃ᵢ = dᵢ + W₁Λ₄Δt ḋᵢ (T̃ = T_D on Dirichlet nodes),
//!   less θ = a/b times the caller's [`HeatSolver::predictor_shift`] (the MPM step's
//!   transfer-consistent correction; none in a grid-only solve);
//! * (b I − β L_h) ΔṪ = r with
//!   rᵢ = −Ṫᵢ − (bτ/D) d̃ᵢ + k [F_T + a(1 − F_T)/D] (L_h T̃)ᵢ + (aτ/D) ḋᵢ + Qᵢ,
//!   solved by conjugate gradients preconditioned with the V-cycle of
//!   [`super::multigrid`] (or Jacobi, for comparison);
//! * Δḋᵢ = −(τ ḋᵢ + d̃ᵢ + (1 − F_T) k (L_h(T̃ + a ΔṪ))ᵢ)/D;
//! * Ṫⁿ⁺¹ = Ṫ + ΔṪ, Tⁿ⁺¹ = T + λ₄Δt Ṫ + λ₅Δt ΔṪ, and the same for (d, ḋ).
//!
//! τ = 0 is the Fourier limit for every F_T (§3.1): d ≡ 0 and the system is the GS4-1 heat
//! equation (b − a k L_h) ΔṪ = −Ṫ + k L_h T̃ + Q (the d-equation is algebraic, D = a would
//! vanish in the start-up evaluation). The start-up rate evaluation of §2.14 (Δt = 0, b = 1,
//! a = 0) gives Ṫ⁰ = −d⁰ + F_T k L_h T⁰ + Q and ḋ⁰ = −(d⁰ + (1 − F_T) k L_h T⁰)/τ.
use thiserror::Error;

use super::multigrid::{
    BlockLattice, LatticeOperator, Multigrid, MultigridError, MultigridParams, NodeClass,
};
use crate::gs4::Gs4Params;
use crate::krylov::{
    CgError, CgInfo, CgParams, CgScratch, IdentityPreconditioner, JacobiPreconditioner,
    LinearOperator, Preconditioner, Reduction, ResidualNorm, Serial, conjugate_gradient_reduced,
};

/// What a heat solve split over several ranks needs from the others (ALGORITHM §12): each rank
/// holds the lattice nodes of its own block columns and, as [`NodeClass::Ghost`] nodes (or the
/// ghosts' true class where they are not unknowns), the nodes of its neighbours within two
/// layers. [`Serial`] is one process: nothing to exchange.
pub trait HeatHalo: Reduction {
    /// Whether the lattice is split over ranks.
    fn split(&self) -> bool;
    /// Overwrites the entries of the nodes other ranks own (within two layers of this rank's)
    /// in every vector of `scalars` and `pairs` with the owners' values. Every rank calls it
    /// together, with the same vectors.
    fn exchange(&self, scalars: &mut [&mut [f64]], pairs: &mut [&mut [[f64; 2]]]);
}

impl HeatHalo for Serial {
    fn split(&self) -> bool {
        false
    }

    fn exchange(&self, _: &mut [&mut [f64]], _: &mut [&mut [[f64; 2]]]) {}
}

/// The operator of a split solve: the ghost entries of x are fetched from their owners before
/// each application (into a copy, so the caller's vectors stay zero off this rank's nodes).
struct HaloOperator<'a, H: HeatHalo> {
    op: &'a mut LatticeOperator,
    halo: &'a H,
    x: &'a mut Vec<f64>,
}

impl<H: HeatHalo> LinearOperator for HaloOperator<'_, H> {
    fn dim(&self) -> usize {
        self.op.len()
    }

    fn apply(&mut self, x: &[f64], y: &mut [f64]) {
        self.x.clear();
        self.x.extend_from_slice(x);
        self.halo.exchange(&mut [&mut self.x[..]], &mut []);
        self.op.apply(self.x, y);
    }
}

/// Preconditioned CG on `op`, through [`HaloOperator`] when the lattice is split.
#[allow(clippy::too_many_arguments)]
fn cg_on<H: HeatHalo>(
    op: &mut LatticeOperator,
    precond: &mut impl Preconditioner,
    rhs: &[f64],
    x: &mut [f64],
    config: &HeatSolverConfig,
    scratch: &mut CgScratch,
    ghost_x: &mut Vec<f64>,
    halo: &H,
) -> Result<CgInfo, CgError> {
    if halo.split() {
        let mut op = HaloOperator {
            op,
            halo,
            x: ghost_x,
        };
        conjugate_gradient_reduced(
            &mut op,
            precond,
            rhs,
            x,
            &config.cg,
            config.norm,
            scratch,
            halo,
        )
    } else {
        conjugate_gradient_reduced(op, precond, rhs, x, &config.cg, config.norm, scratch, halo)
    }
}

/// Thermal parameters of the continuous model of §3.1 (ρc = 1).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatParameters {
    /// Diffusivity k \[m²/s\] (≥ 0).
    pub diffusivity: f64,
    /// Relaxation time τ of the non-Fourier flux \[s\] (≥ 0; 0 = Fourier).
    pub relaxation_time: f64,
    /// Fourier fraction F_T ∈ \[0, 1\] (1 = Fourier, 0 = Cattaneo).
    pub fourier_fraction: f64,
}

/// The scalar coefficients of one heat step (§3.2).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatCoefficients {
    /// a = W₂Λ₅Δt \[s\].
    pub a: f64,
    /// b = W₁Λ₆.
    pub b: f64,
    /// D = bτ + a \[s\] (a when τ = 0).
    pub d: f64,
    /// β = a k (F_T τ b + a)/D \[m²\] (a k when τ = 0).
    pub beta: f64,
    /// W₁Λ₄Δt \[s\].
    pub w1l4_dt: f64,
    /// λ₄Δt \[s\].
    pub l4_dt: f64,
    /// λ₅Δt \[s\].
    pub l5_dt: f64,
    /// The model parameters.
    pub heat: HeatParameters,
}

impl HeatCoefficients {
    /// The coefficients of a step of size `dt` with GS4 parameters `p`, or of the start-up
    /// rate evaluation (§2.14: Δt = 0, W₁Λ₆ = 1) when `rate_evaluation`.
    pub fn new(p: &Gs4Params, dt: f64, rate_evaluation: bool, heat: HeatParameters) -> Self {
        let (w1l4, w1l6, w2l5, l4, l5, dt) = if rate_evaluation {
            (0.0, 1.0, 0.0, 0.0, 0.0, 0.0)
        } else {
            (p.w1l4, p.w1l6, p.w2l5, p.l4, p.l5, dt)
        };
        let a = w2l5 * dt;
        let b = w1l6;
        let (k, tau, f) = (
            heat.diffusivity,
            heat.relaxation_time,
            heat.fourier_fraction,
        );
        let (d, beta) = if tau > 0.0 {
            let d = b * tau + a;
            (d, a * k * (f * tau * b + a) / d)
        } else {
            (a, a * k)
        };
        Self {
            a,
            b,
            d,
            beta,
            w1l4_dt: w1l4 * dt,
            l4_dt: l4 * dt,
            l5_dt: l5 * dt,
            heat,
        }
    }

    /// Whether the flux divergence d is carried (τ > 0).
    pub fn non_fourier(&self) -> bool {
        self.heat.relaxation_time > 0.0
    }
}

/// Preconditioner of the heat CG.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum HeatPreconditioner {
    /// Multigrid, except when the system is so diagonally dominant that the V-cycle cannot pay
    /// for itself: Jacobi when 6β/h² ≤ b (then κ(D⁻¹A) ≤ 3 and Jacobi-PCG needs a handful of
    /// iterations; §3.5: "for small β/Δx² plain Jacobi-PCG may already be enough"). Default.
    #[default]
    Auto,
    /// The multigrid V-cycle of §3.5.
    Multigrid,
    /// Diagonal scaling.
    Jacobi,
    /// None (plain CG).
    None,
}

/// Settings of the heat solve.
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[serde(deny_unknown_fields, default)]
pub struct HeatSolverConfig {
    /// CG tolerances and iteration limit. Default: relative 1e-8, absolute 0, 200 iterations.
    pub cg: CgParams,
    /// Norm of the CG stopping test. Default max-norm (§3.5).
    pub norm: ResidualNorm,
    /// Preconditioner. Default [`HeatPreconditioner::Auto`] (multigrid unless 6β/h² ≤ b).
    pub preconditioner: HeatPreconditioner,
    /// V-cycle parameters (its tolerances are unused when it preconditions CG).
    pub multigrid: MultigridParams,
}

impl Default for HeatSolverConfig {
    fn default() -> Self {
        Self {
            cg: CgParams {
                rel_tol: 1e-8,
                abs_tol: 0.0,
                max_iters: 200,
            },
            norm: ResidualNorm::Max,
            preconditioner: HeatPreconditioner::Auto,
            multigrid: MultigridParams::default(),
        }
    }
}

/// Why a heat step failed.
#[derive(Clone, Copy, Debug, PartialEq, Error)]
pub enum HeatSolveError {
    /// The CG solve failed.
    #[error("heat solve: {0}")]
    Cg(#[from] CgError),
    /// The multigrid parameters are invalid.
    #[error("heat solve: {0}")]
    Multigrid(#[from] MultigridError),
    /// A non-finite value appeared in the right-hand side or the update.
    #[error("heat solve: non-finite {0}")]
    NonFinite(&'static str),
}

/// Nodal heat fields on the solver's lattice (storage indices of [`LatticeOperator`]).
/// Before [`HeatSolver::advance`]: values at tⁿ (Dirichlet nodes hold T_D in `temperature`);
/// after: values at tⁿ⁺¹ and the increments ΔṪ, Δḋ.
#[derive(Clone, Debug, Default)]
pub struct HeatNodes {
    /// Tᵢ.
    pub temperature: Vec<f64>,
    /// Ṫᵢ.
    pub temperature_rate: Vec<f64>,
    /// dᵢ.
    pub flux: Vec<f64>,
    /// ḋᵢ.
    pub flux_rate: Vec<f64>,
    /// Qᵢ \[K/s\].
    pub source: Vec<f64>,
    /// ΔṪᵢ (output).
    pub temperature_increment: Vec<f64>,
    /// Δḋᵢ (output).
    pub flux_increment: Vec<f64>,
}

impl HeatNodes {
    /// Zeroes every field with length `n` (reusing storage).
    pub fn reset(&mut self, n: usize) {
        for v in [
            &mut self.temperature,
            &mut self.temperature_rate,
            &mut self.flux,
            &mut self.flux_rate,
            &mut self.source,
            &mut self.temperature_increment,
            &mut self.flux_increment,
        ] {
            v.clear();
            v.resize(n, 0.0);
        }
    }
}

/// What one heat step did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct HeatStepInfo {
    /// CG result (zero iterations when β = 0, e.g. in the rate evaluation).
    pub cg: CgInfo,
    /// Interior nodes (unknowns).
    pub unknowns: usize,
    /// Multigrid levels used (0 without multigrid).
    pub levels: usize,
}

/// The heat solver: operator, preconditioners and scratch, all reused across steps.
#[derive(Clone, Debug, Default)]
pub struct HeatSolver {
    /// The fine operator (classes of the current step).
    pub operator: LatticeOperator,
    multigrid: Multigrid,
    jacobi: JacobiPreconditioner,
    cg: CgScratch,
    rhs: Vec<f64>,
    t_tilde: Vec<f64>,
    d_tilde: Vec<f64>,
    lap: Vec<f64>,
    /// Latent heat per node, (L/c)ᵢ \[temperature units\] (mass-weighted like T); empty =
    /// none. Set by the caller before [`Self::advance`], with [`Self::melting_band`].
    pub latent: Vec<f64>,
    /// (T_m, ε) of the latent heat: δ_ε(x) = exp(−x²/ε²)/(ε√π).
    pub melting_band: (f64, f64),
    /// Apparent heat capacity Cᵢ = 1 + (L/c)ᵢ δ_ε(T̃ᵢ − T_m) of the current step (§3.1,
    /// Fourier only; empty without latent heat).
    capacity: Vec<f64>,
    /// Transfer defects (D_T, D_d)ᵢ whose multiple θ = a/b = W₂Λ₅Δt/W₁Λ₆ is subtracted from
    /// the predictors (T̃ᵢ, d̃ᵢ) by [`Self::advance`]; empty (or of another length) = none.
    /// Set by the caller before the step (see [`Self::predictor_rates`]).
    pub predictor_shift: Vec<[f64; 2]>,
    /// A split solve's copy of the CG direction with its ghost entries (see `HaloOperator`).
    ghost_x: Vec<f64>,
}

impl HeatSolver {
    /// The apparent heat capacity Cᵢ of the last step (empty without latent heat; 1 on the
    /// nodes that are not Interior).
    pub fn capacity(&self) -> &[f64] {
        &self.capacity
    }

    /// Rebuilds the node classes for a dense box of `core` nodes with spacing `h`
    /// (see [`LatticeOperator::rebuild`]).
    pub fn prepare(
        &mut self,
        core: [usize; 3],
        h: f64,
        class_of: impl FnMut([usize; 3]) -> NodeClass,
    ) {
        self.operator.rebuild(core, h, 1.0, 0.0, class_of);
    }

    /// Rebuilds the node classes on the allocated blocks of `lattice` with spacing `h`
    /// (see [`LatticeOperator::rebuild_on`]).
    pub fn prepare_on(
        &mut self,
        lattice: &BlockLattice,
        core: [usize; 3],
        h: f64,
        class_of: impl FnMut([usize; 3], usize) -> NodeClass,
    ) {
        self.operator
            .rebuild_on(lattice, core, h, 1.0, 0.0, class_of);
    }

    /// Solves (b I − β L_h) x = rhs on the Interior nodes (x from zero), with the configured
    /// preconditioner.
    ///
    /// # Errors
    /// [`HeatSolveError`].
    pub fn solve(
        &mut self,
        config: &HeatSolverConfig,
        b: f64,
        beta: f64,
        rhs: &[f64],
        x: &mut [f64],
    ) -> Result<HeatStepInfo, HeatSolveError> {
        self.solve_with(config, b, beta, rhs, x, &Serial)
    }

    /// [`Self::solve`] on a lattice split over ranks (`halo`; [`HeatHalo`]).
    ///
    /// # Errors
    /// [`HeatSolveError`], the same on every rank.
    pub fn solve_with<H: HeatHalo>(
        &mut self,
        config: &HeatSolverConfig,
        b: f64,
        beta: f64,
        rhs: &[f64],
        x: &mut [f64],
        halo: &H,
    ) -> Result<HeatStepInfo, HeatSolveError> {
        x.fill(0.0);
        let mut info = HeatStepInfo {
            unknowns: self.operator.interior().len(),
            ..Default::default()
        };
        self.operator.set_coefficients(b, beta);
        let scaled = !self.capacity.is_empty();
        if scaled {
            self.operator.scale_capacity(&self.capacity);
        }
        if beta == 0.0 {
            for &i in self.operator.interior() {
                let c = if scaled {
                    self.capacity[i as usize]
                } else {
                    1.0
                };
                x[i as usize] = rhs[i as usize] / (b * c);
            }
            return Ok(info);
        }
        let op = &mut self.operator;
        let h = op.spacing();
        let choice = match config.preconditioner {
            HeatPreconditioner::Auto if 6.0 * beta / (h * h) <= b => HeatPreconditioner::Jacobi,
            HeatPreconditioner::Auto => HeatPreconditioner::Multigrid,
            other => other,
        };
        info.cg = match choice {
            HeatPreconditioner::Multigrid | HeatPreconditioner::Auto => {
                self.multigrid.set_params(config.multigrid)?;
                self.multigrid.setup(op);
                info.levels = self.multigrid.levels();
                cg_on(
                    op,
                    &mut self.multigrid,
                    rhs,
                    x,
                    config,
                    &mut self.cg,
                    &mut self.ghost_x,
                    halo,
                )?
            }
            HeatPreconditioner::Jacobi => {
                op.jacobi_preconditioner(&mut self.jacobi);
                cg_on(
                    op,
                    &mut self.jacobi,
                    rhs,
                    x,
                    config,
                    &mut self.cg,
                    &mut self.ghost_x,
                    halo,
                )?
            }
            HeatPreconditioner::None => cg_on(
                op,
                &mut IdentityPreconditioner,
                rhs,
                x,
                config,
                &mut self.cg,
                &mut self.ghost_x,
                halo,
            )?,
        };
        Ok(info)
    }

    /// Predictors T̃ᵢ = Tᵢ + W₁Λ₄Δt Ṫᵢ, d̃ᵢ = dᵢ + W₁Λ₄Δt ḋᵢ (S3; T_D on Dirichlet nodes, 0
    /// on Exterior ones), minus θ times [`Self::predictor_shift`] when `shifted` (θ = a/b),
    /// the apparent capacity at T̃ (latent heat), and L_h T̃ into `lap`.
    fn predict<H: HeatHalo>(
        &mut self,
        c: &HeatCoefficients,
        nodes: &HeatNodes,
        shifted: bool,
        halo: &H,
    ) {
        let n = self.operator.len();
        for v in [&mut self.t_tilde, &mut self.d_tilde, &mut self.lap] {
            v.clear();
            v.resize(n, 0.0);
        }
        let non_fourier = c.non_fourier();
        let shift = (shifted && self.predictor_shift.len() == n).then_some(&self.predictor_shift);
        let theta = c.a / c.b;
        for (i, class) in self.operator.classes().iter().enumerate() {
            match class {
                NodeClass::Interior => {
                    let s = shift.map_or([0.0; 2], |s| s[i]);
                    self.t_tilde[i] =
                        nodes.temperature[i] + c.w1l4_dt * nodes.temperature_rate[i] - theta * s[0];
                    if non_fourier {
                        self.d_tilde[i] =
                            nodes.flux[i] + c.w1l4_dt * nodes.flux_rate[i] - theta * s[1];
                    }
                }
                NodeClass::Dirichlet => self.t_tilde[i] = nodes.temperature[i],
                NodeClass::Exterior | NodeClass::Ghost => {}
            }
        }
        if halo.split() {
            halo.exchange(&mut [&mut self.t_tilde, &mut self.d_tilde], &mut []);
        }
        // Apparent heat capacity at the predicted temperature (latent heat, §3.1).
        self.capacity.clear();
        if !self.latent.is_empty() {
            let band = super::enthalpy::MeltingBand::new(self.melting_band);
            self.capacity.resize(n, 1.0);
            for &i in self.operator.interior() {
                let i = i as usize;
                self.capacity[i] = band.capacity(self.t_tilde[i], self.latent[i]);
            }
        }
        self.operator.laplacian(&self.t_tilde, &mut self.lap);
    }

    /// The rates (Ṫ, ḋ) of the continuous model (§3.1) at the unshifted predictors T̃, d̃, on
    /// the Interior nodes (zero on the others): C Ṫ = −d̃ + F_T k L_h T̃ + Q and
    /// τ ḋ = −(d̃ + (1 − F_T) k L_h T̃) (ḋ = 0 when τ = 0). `out` is resized to the lattice.
    /// The caller builds [`Self::predictor_shift`] from them (the transfer-consistent
    /// predictor of [`crate::thermal::systems::thermal_solve`]).
    pub fn predictor_rates(
        &mut self,
        c: &HeatCoefficients,
        nodes: &HeatNodes,
        out: &mut Vec<[f64; 2]>,
    ) {
        self.predictor_rates_with(c, nodes, out, &Serial);
    }

    /// [`Self::predictor_rates`] on a lattice split over ranks: the ghosts' rates are the
    /// owners'.
    pub fn predictor_rates_with<H: HeatHalo>(
        &mut self,
        c: &HeatCoefficients,
        nodes: &HeatNodes,
        out: &mut Vec<[f64; 2]>,
        halo: &H,
    ) {
        self.predict(c, nodes, false, halo);
        let HeatParameters {
            diffusivity: k,
            relaxation_time: tau,
            fourier_fraction: f,
        } = c.heat;
        out.clear();
        out.resize(self.operator.len(), [0.0; 2]);
        let scaled = !self.capacity.is_empty();
        for &i in self.operator.interior() {
            let i = i as usize;
            let cap = if scaled { self.capacity[i] } else { 1.0 };
            out[i] = if c.non_fourier() {
                let d = self.d_tilde[i];
                [
                    (-d + f * k * self.lap[i] + nodes.source[i]) / cap,
                    -(d + (1.0 - f) * k * self.lap[i]) / tau,
                ]
            } else {
                [(k * self.lap[i] + nodes.source[i]) / cap, 0.0]
            };
        }
        if halo.split() {
            halo.exchange(&mut [], &mut [out]);
        }
    }

    /// One GS4 C-F heat step on the nodes (module docs), after [`HeatSolver::prepare`].
    /// Dirichlet nodes must hold T_D in `nodes.temperature`.
    ///
    /// # Errors
    /// [`HeatSolveError`]; `nodes` may then be partially updated (the step is abandoned).
    pub fn advance(
        &mut self,
        config: &HeatSolverConfig,
        c: &HeatCoefficients,
        nodes: &mut HeatNodes,
    ) -> Result<HeatStepInfo, HeatSolveError> {
        self.advance_with(config, c, nodes, &Serial)
    }

    /// [`Self::advance`] on a lattice split over ranks (`halo`, [`HeatHalo`]): each rank
    /// updates the Interior nodes it owns, and afterwards holds the owners' new values (and
    /// capacities) on its ghost nodes too.
    ///
    /// # Errors
    /// [`HeatSolveError`], the same on every rank.
    pub fn advance_with<H: HeatHalo>(
        &mut self,
        config: &HeatSolverConfig,
        c: &HeatCoefficients,
        nodes: &mut HeatNodes,
        halo: &H,
    ) -> Result<HeatStepInfo, HeatSolveError> {
        let n = self.operator.len();
        self.rhs.clear();
        self.rhs.resize(n, 0.0);
        let HeatParameters {
            diffusivity: k,
            relaxation_time: tau,
            fourier_fraction: f,
        } = c.heat;
        let non_fourier = c.non_fourier();
        self.predict(c, nodes, true, halo);
        let (c_d, c_l, c_dd) = if non_fourier {
            (c.b * tau / c.d, f + c.a * (1.0 - f) / c.d, c.a * tau / c.d)
        } else {
            (0.0, 1.0, 0.0)
        };
        let scaled = !self.capacity.is_empty();
        for &i in self.operator.interior() {
            let i = i as usize;
            let cap = if scaled { self.capacity[i] } else { 1.0 };
            self.rhs[i] = -cap * nodes.temperature_rate[i] - c_d * self.d_tilde[i]
                + k * c_l * self.lap[i]
                + c_dd * nodes.flux_rate[i]
                + nodes.source[i];
        }
        let bad = self.rhs.iter().any(|v| !v.is_finite());
        if halo.max(f64::from(u8::from(bad))) > 0.0 {
            return Err(HeatSolveError::NonFinite("right-hand side"));
        }
        let rhs = std::mem::take(&mut self.rhs);
        let mut x = std::mem::take(&mut nodes.temperature_increment);
        let result = self.solve_with(config, c.b, c.beta, &rhs, &mut x, halo);
        self.rhs = rhs;
        nodes.temperature_increment = x;
        let info = result?;
        // Δḋ from L_h(T̃ + a ΔṪ) (§3.2; ΔṪ = 0 on Dirichlet nodes).
        nodes.flux_increment.fill(0.0);
        if non_fourier {
            for &i in self.operator.interior() {
                let i = i as usize;
                self.t_tilde[i] += c.a * nodes.temperature_increment[i];
            }
            if halo.split() {
                halo.exchange(&mut [&mut self.t_tilde], &mut []);
            }
            self.operator.laplacian(&self.t_tilde, &mut self.lap);
            for &i in self.operator.interior() {
                let i = i as usize;
                nodes.flux_increment[i] =
                    -(tau * nodes.flux_rate[i] + self.d_tilde[i] + (1.0 - f) * k * self.lap[i])
                        / c.d;
            }
        }
        let mut bad = false;
        for &i in self.operator.interior() {
            let i = i as usize;
            let dtr = nodes.temperature_increment[i];
            let ddr = nodes.flux_increment[i];
            let t = nodes.temperature[i] + c.l4_dt * nodes.temperature_rate[i] + c.l5_dt * dtr;
            let d = nodes.flux[i] + c.l4_dt * nodes.flux_rate[i] + c.l5_dt * ddr;
            if !(t.is_finite() && d.is_finite()) {
                bad = true;
                break;
            }
            nodes.temperature[i] = t;
            nodes.temperature_rate[i] += dtr;
            nodes.flux[i] = d;
            nodes.flux_rate[i] += ddr;
        }
        if halo.max(f64::from(u8::from(bad))) > 0.0 {
            return Err(HeatSolveError::NonFinite("temperature update"));
        }
        if halo.split() {
            let HeatNodes {
                temperature,
                temperature_rate,
                flux,
                flux_rate,
                temperature_increment,
                flux_increment,
                ..
            } = nodes;
            let mut fields: Vec<&mut [f64]> = vec![
                temperature,
                temperature_rate,
                flux,
                flux_rate,
                temperature_increment,
                flux_increment,
            ];
            if !self.capacity.is_empty() {
                fields.push(&mut self.capacity);
            }
            halo.exchange(&mut fields, &mut []);
        }
        Ok(info)
    }
}

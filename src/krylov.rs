//! Krylov solvers over flat `f64` vectors: preconditioned conjugate gradients with a
//! Params / Info / Error API in the style of faer's `conjugate_gradient` (STYLE §7 item 10).
//!
//! The operator and the preconditioner are traits ([`LinearOperator`], [`Preconditioner`]), so
//! a matrix-free grid operator (the implicit viscous solve of ALGORITHM §5.2,
//! [`crate::step::implicit`]) and the thermal multigrid V-cycle of §3.5
//! (`thermal::multigrid::Multigrid`) plug in as operator and preconditioner.
//! Scratch vectors live in [`CgScratch`], which a caller keeps (e.g. in a Bevy resource) and
//! reuses across solves: no allocation once the largest system has been seen.
//!
//! # Determinism
//!
//! Inner products and vector updates run serially in index order, so the iterates are
//! bit-identical for any thread count as long as the operator's `apply` is (the grid operator
//! parallelises its particle passes with a deterministic scatter). Their cost is O(n) per
//! iteration against the operator's O(particles × 27).
//!
//! # Why not faer's own CG
//!
//! faer 0.24 (`faer::matrix_free::conjugate_gradient`, `LinOp` / `Precond` traits) was the
//! first choice. Its `rust-version` (1.84) is fine for our rustc 1.95, but a clean release
//! build of faer alone, with `default-features = false, features = ["std"]` (the least it
//! compiles with; the CG module pulls in its dense linear algebra), took 2 min 55 s wall
//! (1 min 55 s CPU) on this 2-core machine, against ≈ 50 s for the whole Bevy ECS stack
//! (BEVY-NOTES). That buys a loop of about sixty lines. faer's CG is also a block method
//! (a k×k Cholesky per iteration for k right-hand sides) whose vectors must be wrapped as
//! `MatMut` column views of our buffers. The hand-written loop below has the same
//! parameters, information and errors (`CgParams`, `CgInfo`, `CgError::NoConvergence`) and
//! keeps the default build lean. Everything is `f64`: a relative residual of 1e-8 is out of
//! reach in `f32`.
use thiserror::Error;

/// A linear map y = A x on ℝⁿ. For [`conjugate_gradient`] it must be symmetric positive
/// definite on the vectors the iteration produces (the span of the right-hand side's Krylov
/// space).
pub trait LinearOperator {
    /// The dimension n.
    fn dim(&self) -> usize;
    /// Computes `y = A x` (`x` and `y` have length [`LinearOperator::dim`]; `y` is overwritten).
    fn apply(&mut self, x: &[f64], y: &mut [f64]);
}

/// A preconditioner z = M⁻¹ r, symmetric positive definite for [`conjugate_gradient`].
pub trait Preconditioner {
    /// Computes `z = M⁻¹ r` (`z` is overwritten).
    fn apply(&mut self, r: &[f64], z: &mut [f64]);
}

/// The identity preconditioner (plain CG).
#[derive(Clone, Copy, Debug, Default)]
pub struct IdentityPreconditioner;

impl Preconditioner for IdentityPreconditioner {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        z.copy_from_slice(r);
    }
}

/// Diagonal (Jacobi) preconditioner z = r / d, from the operator's diagonal `d` (> 0).
#[derive(Clone, Debug, Default)]
pub struct JacobiPreconditioner {
    /// 1/dᵢ for every unknown.
    pub inverse_diagonal: Vec<f64>,
}

impl Preconditioner for JacobiPreconditioner {
    fn apply(&mut self, r: &[f64], z: &mut [f64]) {
        for ((z, r), d) in z.iter_mut().zip(r).zip(&self.inverse_diagonal) {
            *z = r * d;
        }
    }
}

/// Parameters of [`conjugate_gradient`]. Converged when ‖r‖₂ ≤ max(`abs_tol`, `rel_tol`·‖b‖₂)
/// with r = b − A x (the recursively updated residual).
#[derive(Clone, Copy, Debug, PartialEq, serde::Serialize, serde::Deserialize)]
#[cfg_attr(feature = "reflect", derive(bevy_reflect::Reflect))]
#[serde(deny_unknown_fields, default)]
pub struct CgParams {
    /// Relative tolerance on the residual, against ‖b‖₂. Default `1e-8`.
    pub rel_tol: f64,
    /// Absolute tolerance on the residual, in the units of b. Default `0` (relative only).
    pub abs_tol: f64,
    /// Largest number of iterations; more is [`CgError::NoConvergence`]. Default `500`.
    pub max_iters: usize,
}

impl Default for CgParams {
    fn default() -> Self {
        Self {
            rel_tol: 1e-8,
            abs_tol: 0.0,
            max_iters: 500,
        }
    }
}

impl CgParams {
    /// Checks the parameters; the error names the field and the constraint.
    pub fn validate(&self) -> Result<(), (&'static str, &'static str)> {
        if !(self.rel_tol.is_finite() && self.rel_tol >= 0.0 && self.rel_tol < 1.0) {
            return Err(("rel_tol", "must be a finite number in [0, 1)"));
        }
        if !(self.abs_tol.is_finite() && self.abs_tol >= 0.0) {
            return Err(("abs_tol", "must be a finite number ≥ 0"));
        }
        if self.rel_tol == 0.0 && self.abs_tol == 0.0 {
            return Err(("rel_tol", "rel_tol and abs_tol cannot both be 0"));
        }
        if self.max_iters == 0 {
            return Err(("max_iters", "must be ≥ 1"));
        }
        Ok(())
    }
}

/// What a successful [`conjugate_gradient`] did.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
pub struct CgInfo {
    /// Iterations (operator applications after the initial residual).
    pub iterations: usize,
    /// Final ‖r‖₂.
    pub abs_residual: f64,
    /// Final ‖r‖₂ / ‖b‖₂ (0 when b = 0).
    pub rel_residual: f64,
}

impl CgInfo {
    /// What a solve did, whether or not it succeeded, with residuals relative to ‖b‖ = `b_norm`
    /// (0 when b = 0; NaN residual when the failure left none), and the error if it failed: the
    /// form a caller records in its statistics before reporting the error.
    pub fn of_result(result: Result<CgInfo, CgError>, b_norm: f64) -> (CgInfo, Option<CgError>) {
        let relative = |abs: f64| if b_norm > 0.0 { abs / b_norm } else { 0.0 };
        match result {
            Ok(info) => (
                CgInfo {
                    rel_residual: relative(info.abs_residual),
                    ..info
                },
                None,
            ),
            Err(e) => {
                let (iterations, abs_residual) = match e {
                    CgError::NoConvergence {
                        iterations,
                        abs_residual,
                        ..
                    } => (iterations, abs_residual),
                    CgError::NonPositiveDefiniteOperator { iteration }
                    | CgError::NonPositiveDefinitePreconditioner { iteration }
                    | CgError::NonFinite { iteration } => (iteration, f64::NAN),
                };
                (
                    CgInfo {
                        iterations,
                        abs_residual,
                        rel_residual: relative(abs_residual),
                    },
                    Some(e),
                )
            }
        }
    }
}

/// Why [`conjugate_gradient`] failed. The iterate `x` holds the last (finite) approximation.
#[derive(Clone, Copy, Debug, PartialEq, Error)]
pub enum CgError {
    /// `max_iters` iterations did not reach the tolerance.
    #[error(
        "conjugate gradients did not converge in {iterations} iterations (relative residual {rel_residual:.3e}, absolute {abs_residual:.3e})"
    )]
    NoConvergence {
        /// Iterations done.
        iterations: usize,
        /// ‖r‖₂ at the end.
        abs_residual: f64,
        /// ‖r‖₂ / ‖b‖₂ at the end.
        rel_residual: f64,
    },
    /// pᵀAp ≤ 0 for a search direction p ≠ 0: the operator is not positive definite.
    #[error("the operator is not positive definite (pᵀAp ≤ 0 at iteration {iteration})")]
    NonPositiveDefiniteOperator {
        /// Iteration at which it was detected.
        iteration: usize,
    },
    /// rᵀM⁻¹r < 0 for r ≠ 0: the preconditioner is not positive definite.
    #[error("the preconditioner is not positive definite (rᵀM⁻¹r < 0 at iteration {iteration})")]
    NonPositiveDefinitePreconditioner {
        /// Iteration at which it was detected.
        iteration: usize,
    },
    /// A NaN or infinity appeared (in b, x, the operator or the preconditioner).
    #[error("a non-finite number appeared at iteration {iteration}")]
    NonFinite {
        /// Iteration at which it was detected.
        iteration: usize,
    },
}

/// Work vectors of [`conjugate_gradient`] (r, z, p, A p), grown on demand and reused.
#[derive(Clone, Debug, Default)]
pub struct CgScratch {
    r: Vec<f64>,
    z: Vec<f64>,
    p: Vec<f64>,
    q: Vec<f64>,
}

impl CgScratch {
    fn resize(&mut self, n: usize) {
        for v in [&mut self.r, &mut self.z, &mut self.p, &mut self.q] {
            v.clear();
            v.resize(n, 0.0);
        }
    }
}

/// xᵀy, serial in index order (deterministic).
#[inline]
pub fn dot(x: &[f64], y: &[f64]) -> f64 {
    x.iter().zip(y).map(|(a, b)| a * b).sum()
}

/// Solves A x = b by preconditioned conjugate gradients, starting from the `x` given.
///
/// Standard PCG (Hestenes–Stiefel with a preconditioner M): r₀ = b − A x₀, z = M⁻¹r, p = z;
/// per iteration α = rᵀz / pᵀAp, x += αp, r −= αAp, β = r'ᵀz'/rᵀz, p = z' + βp. The residual
/// is the recursively updated one (no extra operator application per iteration). An all-zero
/// initial guess costs no application (r₀ = b); `iterations` counts the applications after
/// the initial residual.
///
/// # Errors
/// [`CgError`]: no convergence within `params.max_iters`, a non-positive-definite operator or
/// preconditioner, or a non-finite number. `x` then holds the last finite iterate.
pub fn conjugate_gradient(
    op: &mut impl LinearOperator,
    precond: &mut impl Preconditioner,
    b: &[f64],
    x: &mut [f64],
    params: &CgParams,
    scratch: &mut CgScratch,
) -> Result<CgInfo, CgError> {
    conjugate_gradient_in_norm(op, precond, b, x, params, ResidualNorm::Euclidean, scratch)
}

/// The norm in which [`conjugate_gradient_in_norm`] measures residuals.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub enum ResidualNorm {
    /// ‖r‖₂ (the rule of [`conjugate_gradient`]). Default.
    #[default]
    Euclidean,
    /// ‖r‖∞ = maxᵢ |rᵢ|: the stopping rule of the thermal solve of ALGORITHM §3.5
    /// (‖r‖∞ ≤ max(ε_rel‖b‖∞, ε_abs); with the zero initial guess ‖b‖∞ = ‖r₀‖∞).
    Max,
}

impl ResidualNorm {
    /// The norm of `v`, computed serially in index order.
    pub fn of(self, v: &[f64]) -> f64 {
        self.reduced(v, &Serial)
    }

    /// The norm of a vector split over several ranks, `v` being this rank's part (zero on the
    /// entries another rank holds): the partial sum or maximum, combined by `reduce`.
    pub fn reduced(self, v: &[f64], reduce: &impl Reduction) -> f64 {
        match self {
            ResidualNorm::Euclidean => reduce.sum(dot(v, v)).sqrt(),
            ResidualNorm::Max => reduce.max(max_abs(v)),
        }
    }

    /// [`Self::reduced`] of `v` and the sum over the ranks of `local`, in one reduction.
    pub fn reduced_with(self, v: &[f64], local: f64, reduce: &impl Reduction) -> (f64, f64) {
        match self {
            ResidualNorm::Euclidean => {
                let ([vv, s], _) = reduce.sums_and_max([dot(v, v), local], f64::NEG_INFINITY);
                (vv.sqrt(), s)
            }
            ResidualNorm::Max => {
                let ([s, _], m) = reduce.sums_and_max([local, 0.0], max_abs(v));
                (m, s)
            }
        }
    }
}

/// maxᵢ |vᵢ|; NaN propagates (`f64::max` would drop it).
fn max_abs(v: &[f64]) -> f64 {
    v.iter().fold(0.0f64, |m, x| {
        let a = x.abs();
        if a > m || a.is_nan() { a } else { m }
    })
}

/// How the scalars of a solve (inner products, norms, flags) are combined when its vectors are
/// split over several ranks, each holding the entries it owns and zeros elsewhere: the hook of
/// a distributed solve (ALGORITHM §12). Every rank calls the methods in the same order.
pub trait Reduction {
    /// The sum over the ranks of their `local` values (in a fixed order, so the result is
    /// the same bits on every rank).
    fn sum(&self, local: f64) -> f64;
    /// The largest `local` value over the ranks (NaN if any is NaN).
    fn max(&self, local: f64) -> f64;
    /// Two sums and a maximum in one reduction (what [`Self::sum`] and [`Self::max`] give).
    fn sums_and_max(&self, sums: [f64; 2], max: f64) -> ([f64; 2], f64) {
        ([self.sum(sums[0]), self.sum(sums[1])], self.max(max))
    }
    /// Whether a solve should merge its per-iteration reductions (each one costs a round
    /// trip between the ranks); false in one process, where merging would only cost work.
    fn fuses(&self) -> bool {
        false
    }
}

/// One process: every reduction is the identity, so a solve is the serial one, bit for bit.
#[derive(Clone, Copy, Debug, Default)]
pub struct Serial;

impl Reduction for Serial {
    #[inline]
    fn sum(&self, local: f64) -> f64 {
        local
    }

    #[inline]
    fn max(&self, local: f64) -> f64 {
        local
    }
}

/// [`conjugate_gradient`] with the residual (and ‖b‖, and the reported residuals of
/// [`CgInfo`] / [`CgError`]) measured in `norm` instead of the Euclidean norm. The iterates
/// are the same; only the stopping test differs.
///
/// # Errors
/// As [`conjugate_gradient`].
pub fn conjugate_gradient_in_norm(
    op: &mut impl LinearOperator,
    precond: &mut impl Preconditioner,
    b: &[f64],
    x: &mut [f64],
    params: &CgParams,
    norm: ResidualNorm,
    scratch: &mut CgScratch,
) -> Result<CgInfo, CgError> {
    conjugate_gradient_reduced(op, precond, b, x, params, norm, scratch, &Serial)
}

/// [`conjugate_gradient_in_norm`] on a system split over several ranks (ALGORITHM §12): each
/// rank passes its part of b and x (zero on the entries it does not own), an operator whose
/// `apply` fetches the values it needs from the other ranks and writes only owned entries,
/// and a preconditioner that writes only owned entries; every inner product and norm is this
/// rank's partial one combined by `reduce`, so every rank takes the same decisions and the
/// same number of iterations. With [`Serial`] it is [`conjugate_gradient_in_norm`].
///
/// # Errors
/// As [`conjugate_gradient`].
#[allow(clippy::too_many_arguments)]
pub fn conjugate_gradient_reduced(
    op: &mut impl LinearOperator,
    precond: &mut impl Preconditioner,
    b: &[f64],
    x: &mut [f64],
    params: &CgParams,
    norm: ResidualNorm,
    scratch: &mut CgScratch,
    reduce: &impl Reduction,
) -> Result<CgInfo, CgError> {
    let n = op.dim();
    assert_eq!(b.len(), n, "right-hand side length");
    assert_eq!(x.len(), n, "solution length");
    scratch.resize(n);
    let CgScratch { r, z, p, q } = scratch;
    let b_norm = norm.reduced(b, reduce);
    // The state of x on any rank, in one reduction: 2 = not finite, 1 = not zero, 0 = zero.
    let x_state = reduce.max(if x.iter().any(|v| !v.is_finite()) {
        2.0
    } else if x.iter().any(|v| *v != 0.0) {
        1.0
    } else {
        0.0
    });
    if !b_norm.is_finite() || x_state > 1.0 {
        return Err(CgError::NonFinite { iteration: 0 });
    }
    let tol = params.abs_tol.max(params.rel_tol * b_norm);
    let rel = |res: f64| if b_norm > 0.0 { res / b_norm } else { 0.0 };
    // With x = 0, r = b and ‖r‖ = ‖b‖ (no second reduction).
    let mut res = if x_state == 0.0 {
        r.copy_from_slice(b);
        b_norm
    } else {
        op.apply(x, q);
        for ((r, b), q) in r.iter_mut().zip(b).zip(q.iter()) {
            *r = b - q;
        }
        norm.reduced(r, reduce)
    };
    if !res.is_finite() {
        return Err(CgError::NonFinite { iteration: 0 });
    }
    if res <= tol {
        return Ok(CgInfo {
            iterations: 0,
            abs_residual: res,
            rel_residual: rel(res),
        });
    }
    precond.apply(r, z);
    let mut rz = reduce.sum(dot(r, z));
    if rz < 0.0 {
        return Err(CgError::NonPositiveDefinitePreconditioner { iteration: 0 });
    }
    p.copy_from_slice(z);
    for it in 1..=params.max_iters {
        op.apply(p, q);
        let pq = reduce.sum(dot(p, q));
        if !pq.is_finite() {
            return Err(CgError::NonFinite { iteration: it });
        }
        if pq <= 0.0 {
            return Err(CgError::NonPositiveDefiniteOperator { iteration: it });
        }
        let alpha = rz / pq;
        for (x, p) in x.iter_mut().zip(p.iter()) {
            *x += alpha * p;
        }
        for (r, q) in r.iter_mut().zip(q.iter()) {
            *r -= alpha * q;
        }
        // Split over ranks, the residual norm and rᵀz travel in one reduction (the
        // preconditioner then also runs after the last iteration); in one process the norm
        // is checked first, as in the serial algorithm.
        let fused = reduce.fuses().then(|| {
            precond.apply(r, z);
            norm.reduced_with(r, dot(r, z), reduce)
        });
        res = match fused {
            Some((res, _)) => res,
            None => norm.reduced(r, reduce),
        };
        if !res.is_finite() {
            return Err(CgError::NonFinite { iteration: it });
        }
        if res <= tol {
            return Ok(CgInfo {
                iterations: it,
                abs_residual: res,
                rel_residual: rel(res),
            });
        }
        let rz_new = match fused {
            Some((_, rz)) => rz,
            None => {
                precond.apply(r, z);
                reduce.sum(dot(r, z))
            }
        };
        if rz_new < 0.0 {
            return Err(CgError::NonPositiveDefinitePreconditioner { iteration: it });
        }
        let beta = rz_new / rz;
        rz = rz_new;
        for (p, z) in p.iter_mut().zip(z.iter()) {
            *p = z + beta * *p;
        }
    }
    Err(CgError::NoConvergence {
        iterations: params.max_iters,
        abs_residual: res,
        rel_residual: rel(res),
    })
}

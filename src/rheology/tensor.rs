//! Small helpers for symmetric 3×3 tensors in `f64` (stresses, strain rates).
use glam::DMat3;

/// Symmetric part ½(A + Aᵀ).
#[inline]
pub fn sym(a: DMat3) -> DMat3 {
    0.5 * (a + a.transpose())
}

/// Double contraction A:B = Σ_ab A_ab B_ab.
#[inline]
pub fn ddot(a: DMat3, b: DMat3) -> f64 {
    a.x_axis.dot(b.x_axis) + a.y_axis.dot(b.y_axis) + a.z_axis.dot(b.z_axis)
}

/// Trace.
#[inline]
pub fn trace(a: DMat3) -> f64 {
    a.x_axis.x + a.y_axis.y + a.z_axis.z
}

/// Eigenvalues of a symmetric matrix, largest first (closed form of Smith 1961: the roots of
/// the characteristic cubic via the trigonometric formula). Only the symmetric part of `a`
/// is used. Absolute accuracy ≈ 1e-15·‖A‖ for well separated eigenvalues and ≈ 1e-8·‖A‖ for
/// nearly repeated ones (the `acos` near ±1), enough for stability estimates and invariants.
pub fn symmetric_eigenvalues(a: DMat3) -> [f64; 3] {
    let a = sym(a);
    let (a00, a11, a22) = (a.x_axis.x, a.y_axis.y, a.z_axis.z);
    let (a01, a02, a12) = (a.y_axis.x, a.z_axis.x, a.z_axis.y);
    let off = a01 * a01 + a02 * a02 + a12 * a12;
    if off == 0.0 {
        let mut d = [a00, a11, a22];
        d.sort_by(|x, y| y.total_cmp(x));
        return d;
    }
    let q = (a00 + a11 + a22) / 3.0;
    let p2 = (a00 - q).powi(2) + (a11 - q).powi(2) + (a22 - q).powi(2) + 2.0 * off;
    let p = (p2 / 6.0).sqrt();
    let b = (a - DMat3::from_diagonal(glam::DVec3::splat(q))) * (1.0 / p);
    let r = (0.5 * b.determinant()).clamp(-1.0, 1.0);
    let phi = r.acos() / 3.0;
    let e1 = q + 2.0 * p * phi.cos();
    let e3 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
    let e2 = 3.0 * q - e1 - e3;
    [e1, e2, e3]
}

/// Spectral norm ‖A‖₂ = max |eigenvalue| of a symmetric matrix.
#[inline]
pub fn spectral_norm(a: DMat3) -> f64 {
    let e = symmetric_eigenvalues(a);
    e[0].abs().max(e[2].abs())
}

/// Deviator dev A = A − ⅓ tr(A) I.
#[inline]
pub fn deviator(a: DMat3) -> DMat3 {
    a - DMat3::from_diagonal(glam::DVec3::splat(trace(a) / 3.0))
}

/// Frobenius norm ‖A‖_F = √(A:A) (off-diagonal entries of a symmetric tensor count twice,
/// \[Li\] L5).
#[inline]
pub fn frobenius_norm(a: DMat3) -> f64 {
    ddot(a, a).sqrt()
}

/// Polar decomposition F = R S (R proper orthogonal, S symmetric positive definite) of a
/// matrix with det F > 0, by Higham's scaled Newton iteration Xₖ₊₁ = ½(ζXₖ + ζ⁻¹Xₖ⁻ᵀ) →
/// R, then S = sym(Rᵀ F). Converges quadratically; near the identity (small strains) in 3–4
/// iterations. Returns `None` if det F ≤ 0 or F is not finite (no rotation exists / inverted
/// material).
pub fn polar_decomposition(f: DMat3) -> Option<(DMat3, DMat3)> {
    if !f.is_finite() || f.determinant() <= 0.0 {
        return None;
    }
    let mut x = f;
    let mut converged = false;
    for _ in 0..60 {
        let inv_t = x.inverse().transpose();
        // Scaling ζ = (‖X⁻¹‖_F/‖X‖_F)^½ speeds up the start for large stretches; it tends to 1.
        let zeta = if converged {
            1.0
        } else {
            (frobenius_norm(inv_t) / frobenius_norm(x)).sqrt()
        };
        let next = 0.5 * (zeta * x + inv_t * (1.0 / zeta));
        let change = frobenius_norm(next - x);
        x = next;
        if converged {
            break;
        }
        // Quadratic convergence: one more iteration after a change of 1e-9 reaches round-off.
        converged = change <= 1e-9;
    }
    if !x.is_finite() {
        return None;
    }
    Some((x, sym(x.transpose() * f)))
}

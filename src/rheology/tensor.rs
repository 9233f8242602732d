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
/// the characteristic cubic in trigonometric form, λ = q + 2p cos(φ + 2πk/3) with
/// cos 3φ = r). Only the symmetric part of `a` is used.
///
/// c = cos φ is found without `acos`/`cos`: it is the root in \[½, 1\] of the triple-angle
/// identity 4c³ − 3c = r, reached by Halley iterations from a quadratic fit of cos(acos(r)/3)
/// (exact at r = −1, 0, 1), and sin φ = √(1 − c²). Four times cheaper than the libm route,
/// which dominated the XPP model's cost. Absolute accuracy ≈ 1e-15·‖A‖ for well separated
/// eigenvalues and ≈ 1e-8·‖A‖ for nearly repeated ones (the double root of the cubic at
/// r = −1, where the libm route loses the same digits in `acos`), enough for stability
/// estimates and invariants.
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
    let (c1, c3) = cubic_cosines(r);
    let e1 = q + 2.0 * p * c1;
    let e3 = q + 2.0 * p * c3;
    let e2 = 3.0 * q - e1 - e3;
    [e1, e2, e3]
}

/// (cos φ, cos(φ + 2π/3)) with φ = acos(r)/3, r ∈ \[−1, 1\]: the largest and the smallest
/// root of the triple-angle cubic 4c³ − 3c − r = 0. Each is found by Halley iterations where
/// it is a simple, well-conditioned root (|f′| ≥ 6): cos φ ∈ \[√3/2, 1\] for r ≥ 0, and
/// cos(φ + 2π/3) ∈ \[−1, −√3/2\] for r < 0; the other one follows from sin φ (r ≥ 0) or from
/// deflating the cubic (r < 0, roots c₁ + c₂ = −c₃, c₁c₂ = r/(4c₃)). Agrees with the libm
/// route to ≈ 3e-14 over the whole range (unit test below).
#[inline]
fn cubic_cosines(r: f64) -> (f64, f64) {
    let half_sqrt3 = 0.5 * 3f64.sqrt();
    let halley = |mut c: f64| {
        // Cubic convergence from guesses within 0.04 of the root: two iterations reach 9e-15
        // and three 3e-16 over the whole range. Three, because near a repeated eigenvalue
        // (r → ±1) the other root comes from √(1 − c₁²), which amplifies the error of c₁ to
        // its square root (tests/rheology.rs `symmetric_eigenvalues_closed_form`).
        for _ in 0..3 {
            let f = (4.0 * c * c - 3.0) * c - r;
            let df = 12.0 * c * c - 3.0;
            c -= 2.0 * f * df / (2.0 * df * df - f * 24.0 * c);
        }
        c
    };
    if r >= 0.0 {
        // Guess: the quadratic through (0, √3/2), (1, 1) and (−1, ½).
        let c1 = halley(half_sqrt3 + 0.25 * r + (0.75 - half_sqrt3) * r * r).min(1.0);
        let s = (1.0 - c1 * c1).max(0.0).sqrt();
        (c1, -0.5 * c1 - half_sqrt3 * s)
    } else {
        // Guess: the line through (0, −√3/2) and (−1, −1).
        let c3 = halley(-half_sqrt3 + (1.0 - half_sqrt3) * r).max(-1.0);
        let disc = (c3 * c3 - r / c3).max(0.0);
        (0.5 * (-c3 + disc.sqrt()), c3)
    }
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

#[cfg(test)]
mod eigen_tests {
    use super::*;
    use glam::DVec3;

    /// The Halley route agrees with the libm route (acos, cos) on random symmetric matrices,
    /// and the eigenvalues reproduce the trace and the determinant.
    #[test]
    fn matches_trigonometric_route() {
        let mut x = 0x2545_F491_4F6C_DD1Du64;
        let mut next = || {
            x ^= x << 13;
            x ^= x >> 7;
            x ^= x << 17;
            (x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
        };
        let mut worst: f64 = 0.0;
        for _ in 0..20_000 {
            let m = DMat3::from_cols(
                DVec3::new(next(), next(), next()),
                DVec3::new(next(), next(), next()),
                DVec3::new(next(), next(), next()),
            ) * 10.0;
            let a = sym(m);
            let e = symmetric_eigenvalues(a);
            // Reference: the libm trigonometric formula.
            let q = trace(a) / 3.0;
            let d = a - DMat3::from_diagonal(DVec3::splat(q));
            let p = (ddot(d, d) / 6.0).sqrt();
            let r = (0.5 * (d * (1.0 / p)).determinant()).clamp(-1.0, 1.0);
            let phi = r.acos() / 3.0;
            let e1 = q + 2.0 * p * phi.cos();
            let e3 = q + 2.0 * p * (phi + 2.0 * std::f64::consts::FRAC_PI_3).cos();
            let norm = e1.abs().max(e3.abs());
            worst = worst.max((e[0] - e1).abs().max((e[2] - e3).abs()) / norm);
            assert!(e[0] >= e[1] - 1e-9 * norm && e[1] >= e[2] - 1e-9 * norm);
            assert!((e[0] + e[1] + e[2] - trace(a)).abs() < 1e-12 * norm);
            assert!((e[0] * e[1] * e[2] - a.determinant()).abs() < 1e-9 * norm.powi(3));
        }
        assert!(worst < 1e-12, "worst relative difference {worst:e}");
        // Repeated eigenvalues (r = ±1) and a diagonal matrix.
        for a in [
            DMat3::from_diagonal(DVec3::new(2.0, 2.0, -1.0)),
            DMat3::from_diagonal(DVec3::new(3.0, -1.0, -1.0)),
        ] {
            let rot = DMat3::from_axis_angle(DVec3::new(1.0, 2.0, 3.0).normalize(), 0.7);
            let e = symmetric_eigenvalues(rot * a * rot.transpose());
            let mut want = [a.x_axis.x, a.y_axis.y, a.z_axis.z];
            want.sort_by(|x, y| y.total_cmp(x));
            for k in 0..3 {
                assert!((e[k] - want[k]).abs() < 1e-7, "{e:?} vs {want:?}");
            }
        }
    }
}

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
/// identity 4c³ − 3c = r, reached by one Halley iteration from a polynomial fit of
/// cos(acos(|r|)/3) (`cubic_cosines`), and sin φ = √(1 − c²). Written as a short dependency
/// chain (one square root, one division, one Halley step, one square root) because the XPP model
/// (ALGORITHM §2.8, ‖σ̂‖₂ in K) is bound by its latency, not by its instruction count
/// (BENCHMARKS.md (e)). Absolute accuracy ≈ 1e-15·‖A‖ for well separated eigenvalues and
/// ≈ 1e-8·‖A‖ for nearly repeated ones (the double root of the cubic at r = ±1, where the libm
/// route loses the same digits in `acos`), enough for stability estimates and invariants.
pub fn symmetric_eigenvalues(a: DMat3) -> [f64; 3] {
    let a = sym(a);
    upper_eigenvalues(
        [a.x_axis.x, a.y_axis.y, a.z_axis.z],
        [a.y_axis.x, a.z_axis.x, a.z_axis.y],
    )
}

/// [`symmetric_eigenvalues`] of the symmetric matrix with diagonal `[a00, a11, a22]` and
/// off-diagonal entries `[a01, a02, a12]` (for a matrix known to be symmetric, this skips
/// the symmetrisation, which leaves an exactly symmetric matrix unchanged anyway).
#[inline]
pub fn upper_eigenvalues(diagonal: [f64; 3], off_diagonal: [f64; 3]) -> [f64; 3] {
    let [a00, a11, a22] = diagonal;
    let [a01, a02, a12] = off_diagonal;
    let off = a01 * a01 + a02 * a02 + a12 * a12;
    if off == 0.0 {
        let mut d = [a00, a11, a22];
        d.sort_by(|x, y| y.total_cmp(x));
        return d;
    }
    let q = (a00 + a11 + a22) * (1.0 / 3.0);
    let (d00, d11, d22) = (a00 - q, a11 - q, a22 - q);
    // p² = ‖A − qI‖²_F / 6, and det(A − qI) computed alongside it (not from (A − qI)/p, which
    // would wait for √ and a division).
    let p2 = (d00 * d00 + d11 * d11 + d22 * d22 + 2.0 * off) * (1.0 / 6.0);
    let det = d00 * (d11 * d22 - a12 * a12) - a01 * (a01 * d22 - a12 * a02)
        + a02 * (a01 * a12 - d11 * a02);
    let p = p2.sqrt();
    let p3 = p2 * p;
    // r = det((A − qI)/p)/2. Dividing by p³ directly is exact enough but over- or underflows
    // for |A| beyond ≈ 1e±100 (stresses that relaxed for many λ_b): then scale first.
    let r = if p3 > 1e-250 && p3 < 1e250 {
        0.5 * det / p3
    } else {
        let inv_p = 1.0 / p;
        let b = DMat3::from_cols(
            glam::DVec3::new(d00, a01, a02),
            glam::DVec3::new(a01, d11, a12),
            glam::DVec3::new(a02, a12, d22),
        ) * inv_p;
        0.5 * b.determinant()
    };
    let (c1, c3) = cubic_cosines(r.clamp(-1.0, 1.0));
    let e1 = q + 2.0 * p * c1;
    let e3 = q + 2.0 * p * c3;
    let e2 = 3.0 * q - e1 - e3;
    [e1, e2, e3]
}

/// Least-squares fit of degree 5 of cos(acos(u)/3) on u ∈ \[0, 1\] (Chebyshev nodes), a
/// polynomial in u with these coefficients; its error is below 5.8e-7 everywhere on \[0, 1\].
const COS_THIRD_ACOS_FIT: [f64; 6] = [
    0.8660259824479152,
    0.16662256394687075,
    -0.04755362588792103,
    0.021977785571925885,
    -0.009054171952556412,
    0.0019819065984639614,
];

/// (cos φ, cos(φ + 2π/3)) with φ = acos(r)/3, r ∈ \[−1, 1\]: the largest and the smallest
/// root of the triple-angle cubic 4c³ − 3c − r = 0.
///
/// The roots for r are the negatives of those for −r, so only the largest root u of
/// 4u³ − 3u = |r| is solved for: u = cos(acos(|r|)/3) ∈ \[√3/2, 1\], a simple,
/// well-conditioned root (|f′| ≥ 6). The fit [`COS_THIRD_ACOS_FIT`] is within 5.8e-7 of it and
/// one Halley iteration (cubic convergence) reaches it to 1 ulp over the whole range. The
/// smallest root for |r| is −u/2 − (√3/2)√(1 − u²); for r < 0 the pair is negated and
/// swapped. Near a repeated eigenvalue (|r| → 1) √(1 − u²) amplifies the error of u to its
/// square root (tests/it/rheology.rs `symmetric_eigenvalues_closed_form`). Agrees with the libm
/// route to ≈ 3e-14 over the whole range (unit test below). Branch-free but for the selection.
#[inline]
fn cubic_cosines(r: f64) -> (f64, f64) {
    let half_sqrt3 = 0.5 * 3f64.sqrt();
    let u = r.abs();
    let k = COS_THIRD_ACOS_FIT;
    // Estrin's scheme: a shorter dependency chain than Horner's.
    let u2 = u * u;
    let g = (k[0] + k[1] * u) + u2 * ((k[2] + k[3] * u) + u2 * (k[4] + k[5] * u));
    let f = (4.0 * g * g - 3.0) * g - u;
    let df = 12.0 * g * g - 3.0;
    let c = (g - 2.0 * f * df / (2.0 * df * df - f * 24.0 * g)).min(1.0);
    let s = ((1.0 - c) * (1.0 + c)).max(0.0).sqrt();
    let other = -0.5 * c - half_sqrt3 * s;
    if r >= 0.0 { (c, other) } else { (-other, -c) }
}

/// Spectral norm ‖A‖₂ = max |eigenvalue| of a symmetric matrix.
#[inline]
pub fn spectral_norm(a: DMat3) -> f64 {
    let e = symmetric_eigenvalues(a);
    e[0].abs().max(e[2].abs())
}

/// [`spectral_norm`] of a matrix known to be exactly symmetric (reads its upper triangle;
/// the same result as `spectral_norm` then).
#[inline]
pub fn symmetric_spectral_norm(a: DMat3) -> f64 {
    let e = upper_eigenvalues(
        [a.x_axis.x, a.y_axis.y, a.z_axis.z],
        [a.y_axis.x, a.z_axis.x, a.z_axis.y],
    );
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

/// A deterministic xorshift stream of 3×3 matrices with entries uniform in [−1, 1), for the
/// unit tests of this module and of the models.
#[cfg(test)]
pub(crate) struct TestMatrices(pub u64);

#[cfg(test)]
impl TestMatrices {
    fn next_value(&mut self) -> f64 {
        let x = &mut self.0;
        *x ^= *x << 13;
        *x ^= *x >> 7;
        *x ^= *x << 17;
        (*x >> 11) as f64 / (1u64 << 53) as f64 * 2.0 - 1.0
    }

    /// The next matrix.
    pub(crate) fn next_matrix(&mut self) -> DMat3 {
        let mut col = || glam::DVec3::new(self.next_value(), self.next_value(), self.next_value());
        let (a, b, c) = (col(), col(), col());
        DMat3::from_cols(a, b, c)
    }
}

#[cfg(test)]
mod eigen_tests {
    use super::*;
    use glam::DVec3;

    /// The Halley route agrees with the libm route (acos, cos) on random symmetric matrices,
    /// and the eigenvalues reproduce the trace and the determinant.
    #[test]
    fn matches_trigonometric_route() {
        let mut rng = TestMatrices(0x2545_F491_4F6C_DD1D);
        let mut worst: f64 = 0.0;
        for _ in 0..20_000 {
            let m = rng.next_matrix() * 10.0;
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
        // Far outside the range where det/p³ is formed directly (scaled route).
        let a = sym(DMat3::from_cols(
            DVec3::new(3.0, 1.0, -2.0),
            DVec3::new(0.5, -1.0, 0.25),
            DVec3::new(1.5, 2.0, 0.7),
        ));
        let e = symmetric_eigenvalues(a);
        for scale in [1e-150, 1e-120, 1e120, 1e150] {
            let es = symmetric_eigenvalues(a * scale);
            for k in 0..3 {
                assert!(
                    (es[k] / scale - e[k]).abs() < 1e-13 * e[0].abs(),
                    "{es:?} vs {e:?}"
                );
            }
            assert_eq!(symmetric_spectral_norm(a * scale), spectral_norm(a * scale));
        }
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

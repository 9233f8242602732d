//! The melting band's enthalpy (ALGORITHM §3.4, latent heat): with latent heat L/c released
//! over a Gaussian band of width ε around T_m, the heat content per unit heat capacity is
//!
//! H(T) = T + (L/c) φ(T),  φ(T) = ½(1 + erf((T − T_m)/ε)),  H′(T) = 1 + (L/c) δ_ε(T − T_m),
//!
//! with φ the melted fraction and δ_ε(x) = exp(−x²/ε²)/(ε√π). The grid solve uses the apparent
//! capacity H′ at the predictor; the particles carry T and update it through H, so that a node
//! that crosses the band within one step (narrow bands, large steps) cannot skip the latent heat.

/// A melting band: T_m and the width ε of the Gaussian δ_ε.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct MeltingBand {
    /// Melting temperature T_m.
    pub melting_temperature: f64,
    /// Width ε (> 0).
    pub width: f64,
}

impl MeltingBand {
    /// The band (T_m, ε).
    pub fn new((melting_temperature, width): (f64, f64)) -> Self {
        Self {
            melting_temperature,
            width,
        }
    }

    /// Melted fraction φ(T) ∈ (0, 1).
    #[inline]
    pub fn fraction(&self, t: f64) -> f64 {
        0.5 * (1.0 + libm::erf((t - self.melting_temperature) / self.width))
    }

    /// δ_ε(T − T_m) = φ′(T).
    #[inline]
    pub fn delta(&self, t: f64) -> f64 {
        let x = (t - self.melting_temperature) / self.width;
        (-x * x).exp() / (self.width * std::f64::consts::PI.sqrt())
    }

    /// H(T) for latent heat `latent` = L/c.
    #[inline]
    pub fn enthalpy(&self, t: f64, latent: f64) -> f64 {
        t + latent * self.fraction(t)
    }

    /// H′(T) = 1 + (L/c) δ_ε(T − T_m) ≥ 1.
    #[inline]
    pub fn capacity(&self, t: f64, latent: f64) -> f64 {
        1.0 + latent * self.delta(t)
    }

    /// The temperature T with H(T) = `h`, from a starting `guess`: safeguarded Newton. Since
    /// H′ ≥ 1 the root lies within |H(guess) − h| of the guess, which brackets it.
    pub fn temperature(&self, h: f64, latent: f64, guess: f64) -> f64 {
        if latent == 0.0 {
            return h;
        }
        let g = |t: f64| self.enthalpy(t, latent) - h;
        let g0 = g(guess);
        if g0 == 0.0 {
            return guess;
        }
        let (mut lo, mut hi) = if g0 > 0.0 {
            (guess - g0, guess)
        } else {
            (guess, guess - g0)
        };
        let mut t = guess;
        let tol = 1e-14 * (1.0 + h.abs() + latent);
        for _ in 0..100 {
            let gt = g(t);
            if gt.abs() <= tol {
                return t;
            }
            if gt > 0.0 {
                hi = t;
            } else {
                lo = t;
            }
            let newton = t - gt / self.capacity(t, latent);
            t = if newton > lo && newton < hi {
                newton
            } else {
                0.5 * (lo + hi)
            };
            if hi - lo <= tol {
                break;
            }
        }
        t
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// H⁻¹(H(T)) = T across and far from the band, from poor guesses, and H′ is the derivative
    /// of H (central difference, error O(h²) ≈ 1e-8 relative at h = 1e-5 ε).
    #[test]
    fn enthalpy_inverts_and_differentiates() {
        let band = MeltingBand::new((0.5, 0.01));
        for latent in [0.0, 0.5, 10.0] {
            for i in 0..=200 {
                let t = -1.0 + 0.01 * i as f64;
                let h = band.enthalpy(t, latent);
                for guess in [t - 3.0, t, t + 0.7, 0.5] {
                    let back = band.temperature(h, latent, guess);
                    assert!((back - t).abs() < 1e-12, "L {latent}: T {t} → {back}");
                }
                let d = 1e-7;
                let fd = (band.enthalpy(t + d, latent) - band.enthalpy(t - d, latent)) / (2.0 * d);
                let c = band.capacity(t, latent);
                assert!((fd - c).abs() < 1e-6 * c, "L {latent}: H′({t}) {c} vs {fd}");
            }
        }
    }
}

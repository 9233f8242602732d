//! Coil tracking: where a falling liquid rope meets its pile, and how fast that point turns
//! about the nozzle's axis (docs/gallery.md, `coiling_1.ron`; `examples/coil_track.rs`).
//!
//! # Measure
//!
//! ```text
//! band B = { particles with y₀ ≤ y < y₁ }        (a horizontal slab the rope crosses once)
//! centroid c = mean over B of (x, z);  offset d = c − a  (a = the axis point (x, z))
//! radius r = |d|,  angle φ = atan2(d_z, d_x)     (per frame; none if |B| < n_min)
//! φ unwrapped across frames (jumps > π taken as the short way round)
//! angular frequency Ω = least-squares slope of φ(t);  turns = (φ_end − φ_start)/2π
//! ```
//!
//! A sheet that folds in the x–y plane ([`fold_rate`]) moves its crossing back and forth along
//! x: each crossing of its mean position is one fold, and two make the fold period.
//!
//! A rope that coils crosses the band at one point that circles the axis: r stays near the coil
//! radius and φ grows steadily (Ω ≠ 0, several turns). A rope that folds back and forth
//! (buckling without rotation) gives φ swinging by π with no net turns; a straight rope gives r
//! near 0.

/// One frame's rope crossing of the band.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoilSample {
    /// Simulation time \[s\].
    pub time: f64,
    /// Distance of the band's centroid from the axis \[m\].
    pub radius: f64,
    /// Angle of the centroid about the axis \[rad\], in (−π, π\].
    pub angle: f64,
    /// Particles in the band.
    pub count: usize,
}

/// The band's centroid of one frame, or `None` if fewer than `min_count` particles lie in
/// the band `y_band` = (y₀, y₁) \[m\]. `axis` is the (x, z) point of the vertical axis \[m\].
pub fn coil_sample(
    time: f64,
    positions: impl IntoIterator<Item = [f64; 3]>,
    axis: [f64; 2],
    y_band: (f64, f64),
    min_count: usize,
) -> Option<CoilSample> {
    let (mut sx, mut sz, mut n) = (0.0, 0.0, 0usize);
    for [x, y, z] in positions {
        if y >= y_band.0 && y < y_band.1 {
            sx += x;
            sz += z;
            n += 1;
        }
    }
    if n == 0 || n < min_count {
        return None;
    }
    let (dx, dz) = (sx / n as f64 - axis[0], sz / n as f64 - axis[1]);
    Some(CoilSample {
        time,
        radius: dx.hypot(dz),
        angle: dz.atan2(dx),
        count: n,
    })
}

/// Angles of `samples` unwrapped into a continuous curve (each step taken as the short way
/// round, so frames must be closer than half a turn apart).
pub fn unwrap_angles(samples: &[CoilSample]) -> Vec<f64> {
    let mut out = Vec::with_capacity(samples.len());
    let mut offset = 0.0;
    let mut prev: Option<f64> = None;
    for s in samples {
        if let Some(p) = prev {
            let mut d = s.angle - p;
            while d > std::f64::consts::PI {
                d -= std::f64::consts::TAU;
                offset -= std::f64::consts::TAU;
            }
            while d < -std::f64::consts::PI {
                d += std::f64::consts::TAU;
                offset += std::f64::consts::TAU;
            }
        }
        prev = Some(s.angle);
        out.push(s.angle + offset);
    }
    out
}

/// The coil's rate over a window of samples.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct CoilRate {
    /// Samples used.
    pub samples: usize,
    /// Mean radius \[m\].
    pub mean_radius: f64,
    /// Angular frequency Ω \[rad/s\]: least-squares slope of the unwrapped angle (sign: the
    /// sense of rotation, counter-clockwise seen from above the x–z plane is positive).
    pub angular_frequency: f64,
    /// Net turns (φ_end − φ_start)/2π.
    pub turns: f64,
}

/// The rate of the samples with `window.0 ≤ t ≤ window.1` \[s\]; `None` with fewer than 3.
pub fn coil_rate(samples: &[CoilSample], window: (f64, f64)) -> Option<CoilRate> {
    let inside: Vec<CoilSample> = samples
        .iter()
        .copied()
        .filter(|s| s.time >= window.0 && s.time <= window.1)
        .collect();
    if inside.len() < 3 {
        return None;
    }
    let phi = unwrap_angles(&inside);
    let n = inside.len() as f64;
    let t_mean = inside.iter().map(|s| s.time).sum::<f64>() / n;
    let p_mean = phi.iter().sum::<f64>() / n;
    let (mut stp, mut stt) = (0.0, 0.0);
    for (s, p) in inside.iter().zip(&phi) {
        stp += (s.time - t_mean) * (p - p_mean);
        stt += (s.time - t_mean).powi(2);
    }
    Some(CoilRate {
        samples: inside.len(),
        mean_radius: inside.iter().map(|s| s.radius).sum::<f64>() / n,
        angular_frequency: if stt > 0.0 { stp / stt } else { 0.0 },
        turns: (phi[phi.len() - 1] - phi[0]) / std::f64::consts::TAU,
    })
}

/// A folding sheet's rate: how often its band crossing swings back and forth along x.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct FoldRate {
    /// Frames inside the window.
    pub samples: usize,
    /// Crossings of the mean position inside the window (one per fold laid).
    pub crossings: usize,
    /// Fold period \[s\]: twice the mean time between successive crossings (a full back-and-forth).
    pub period: f64,
    /// Largest distance of the crossing from its mean position along x \[m\].
    pub amplitude: f64,
}

/// The fold period of a sheet that folds in the x–y plane: the offset along x of each sample
/// (`radius · cos(angle)`, [`coil_sample`]) about its mean over `window`; each sign change
/// (linearly interpolated in time) is one fold. `None` with fewer than two crossings.
pub fn fold_rate(samples: &[CoilSample], window: (f64, f64)) -> Option<FoldRate> {
    let inside: Vec<(f64, f64)> = samples
        .iter()
        .filter(|s| s.time >= window.0 && s.time <= window.1)
        .map(|s| (s.time, s.radius * s.angle.cos()))
        .collect();
    if inside.len() < 3 {
        return None;
    }
    let mean = inside.iter().map(|p| p.1).sum::<f64>() / inside.len() as f64;
    let mut crossings = Vec::new();
    for w in inside.windows(2) {
        let ((t0, x0), (t1, x1)) = (w[0], w[1]);
        let (a, b) = (x0 - mean, x1 - mean);
        if a != 0.0 && a.signum() != b.signum() {
            crossings.push(t0 + (t1 - t0) * a / (a - b));
        }
    }
    if crossings.len() < 2 {
        return None;
    }
    let span = crossings[crossings.len() - 1] - crossings[0];
    Some(FoldRate {
        samples: inside.len(),
        crossings: crossings.len(),
        period: 2.0 * span / (crossings.len() - 1) as f64,
        amplitude: inside
            .iter()
            .map(|p| (p.1 - mean).abs())
            .fold(0.0, f64::max),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A point circling the axis at radius 5 mm with Ω = 20 rad/s, sampled at 50 frames/s
    /// (0.4 rad per frame, well under half a turn): the rate recovers Ω, the radius and the
    /// turns to rounding; a point swinging back and forth across the axis has no net turns.
    #[test]
    fn rate_of_a_circling_point_and_of_a_swinging_one() {
        let axis = [0.03, 0.03];
        let circle: Vec<CoilSample> = (0..100)
            .map(|k| {
                let t = k as f64 / 50.0;
                let (s, c) = (20.0 * t).sin_cos();
                let p = [axis[0] + 0.005 * c, 0.01, axis[1] + 0.005 * s];
                // Two particles in the band, one outside.
                let pts = [p, p, [0.0, 0.5, 0.0]];
                coil_sample(t, pts, axis, (0.0, 0.02), 2).unwrap()
            })
            .collect();
        let r = coil_rate(&circle, (0.0, 2.0)).unwrap();
        assert_eq!(r.samples, 100);
        assert!((r.angular_frequency - 20.0).abs() < 1e-9, "{r:?}");
        assert!((r.mean_radius - 0.005).abs() < 1e-12, "{r:?}");
        assert!(
            (r.turns - 20.0 * 1.98 / std::f64::consts::TAU).abs() < 1e-9,
            "{r:?}"
        );
        let swing: Vec<CoilSample> = (0..100)
            .map(|k| {
                let t = k as f64 / 50.0;
                let x = axis[0] + 0.005 * (20.0 * t).sin();
                coil_sample(t, [[x, 0.01, axis[1] + 1e-4]], axis, (0.0, 0.02), 1).unwrap()
            })
            .collect();
        let r = coil_rate(&swing, (0.0, 2.0)).unwrap();
        assert!(r.turns.abs() < 0.5, "{r:?}");
        assert!(coil_sample(0.0, [[0.0, 0.5, 0.0]], axis, (0.0, 0.02), 1).is_none());
        // The swing has period 2π/20 s and amplitude 5 mm; the circle folds too when seen
        // along x only, with the same period.
        let f = fold_rate(&swing, (0.0, 2.0)).unwrap();
        let period = std::f64::consts::TAU / 20.0;
        assert!((f.period / period - 1.0).abs() < 0.01, "{f:?}");
        assert!((f.amplitude - 0.005).abs() < 2e-4, "{f:?}");
        assert!(f.crossings >= 12, "{f:?}");
        let f = fold_rate(&circle, (0.0, 2.0)).unwrap();
        assert!((f.period / period - 1.0).abs() < 0.01, "{f:?}");
        // A rope at rest off the axis does not fold.
        let still: Vec<CoilSample> = (0..50)
            .map(|k| coil_sample(k as f64 / 50.0, [[0.035, 0.01, 0.03]], axis, (0.0, 0.02), 1))
            .map(Option::unwrap)
            .collect();
        assert!(fold_rate(&still, (0.0, 2.0)).is_none());
    }
}

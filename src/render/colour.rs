//! Colour maps of the particle field, as linear-RGBA lookup tables for the GPU.
use crate::plot::viridis;

/// Entries of a lookup table (the shader picks the nearest one: 256 levels are finer than
/// 8-bit output can show between neighbours).
pub const LUT_SIZE: usize = 256;

/// A perceptual colour map (low values first).
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub enum ColourMap {
    /// Viridis: dark purple → blue → green → yellow; perceptually uniform, readable in grey
    /// and by colour-blind viewers (the map of `treacle snapshot`, [`crate::plot::viridis`]).
    #[default]
    Viridis,
}

/// sRGB-encoded 8-bit channel → linear \[0, 1\] (IEC 61966-2-1).
pub fn srgb_to_linear(c: u8) -> f32 {
    let c = c as f32 / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// The sRGB colour of `map` at `t ∈ [0, 1]`.
pub fn colour_srgb(map: ColourMap, t: f64) -> [u8; 3] {
    match map {
        ColourMap::Viridis => {
            let c = viridis(t);
            [c.0, c.1, c.2]
        }
    }
}

/// [`LUT_SIZE`] linear-RGBA entries of `map` (alpha 1), for the particle shader.
pub fn colour_map_lut(map: ColourMap) -> Vec<[f32; 4]> {
    (0..LUT_SIZE)
        .map(|i| {
            let [r, g, b] = colour_srgb(map, i as f64 / (LUT_SIZE - 1) as f64);
            [srgb_to_linear(r), srgb_to_linear(g), srgb_to_linear(b), 1.0]
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn lut_runs_from_dark_purple_to_yellow_in_linear_space() {
        let lut = colour_map_lut(ColourMap::Viridis);
        assert_eq!(lut.len(), LUT_SIZE);
        let (first, last) = (lut[0], lut[LUT_SIZE - 1]);
        // Viridis starts dark (blue > green) and ends bright yellow (red, green > blue).
        assert!(first[2] > first[1] && first[0] + first[1] + first[2] < 0.3);
        assert!(last[0] > 0.7 && last[1] > 0.7 && last[2] < 0.1);
        // sRGB decoding: 255 → 1, 0 → 0, mid-grey 128 → 0.2158 (the standard curve).
        assert_eq!(srgb_to_linear(255), 1.0);
        assert_eq!(srgb_to_linear(0), 0.0);
        assert!((srgb_to_linear(128) - 0.2158).abs() < 1e-3);
    }
}

//! Surface appearance: albedo, specular highlight and a procedural pattern evaluated per pixel
//! at the surface point in the mesh's own frame (so textures stick to moving objects), plus the
//! smooth value noise the patterns and the procedural assets share.

pub use crate::noise::value_noise3;
use crate::noise::{floor_i32, lattice_hash};

/// A procedural surface pattern. Lengths are metres in the mesh frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum Pattern {
    Solid,
    /// Woven threads along x and y with the given period (gauze).
    Weave {
        period_m: f32,
        contrast: f32,
    },
    /// Smooth mottling (tissue, pads) of the given feature size.
    Mottled {
        scale_m: f32,
        contrast: f32,
        seed: u32,
    },
    /// Fine lines along y (machined metal, plastic).
    Brushed {
        period_m: f32,
        contrast: f32,
    },
}

/// How a surface reflects the endoscope's light. Colours are linear RGB in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Material {
    pub albedo: [f32; 3],
    /// Strength of the specular highlight (0 = matte).
    pub specular: f32,
    /// The highlight's exponent is `2^shininess_log2` (computed by repeated squaring).
    pub shininess_log2: u8,
    pub pattern: Pattern,
    /// Light at the vertices and interpolate (Gouraud) instead of per pixel: for dense or flat
    /// meshes with soft highlights, where it looks the same at a fraction of the cost. Per-pixel
    /// patterns are not drawn then; bake them into the mesh instead.
    pub per_vertex: bool,
}

impl Material {
    /// A matte solid colour given in sRGB bytes.
    pub fn matte(srgb: [u8; 3]) -> Self {
        Material {
            albedo: srgb.map(srgb_to_linear),
            specular: 0.0,
            per_vertex: false,
            shininess_log2: 0,
            pattern: Pattern::Solid,
        }
    }

    /// The same material with a highlight.
    pub fn glossy(self, specular: f32, shininess_log2: u8) -> Self {
        Material {
            specular,
            shininess_log2,
            ..self
        }
    }

    /// The same material lit per vertex (see [`Material::per_vertex`]).
    pub fn per_vertex(self) -> Self {
        Material {
            per_vertex: true,
            ..self
        }
    }

    /// The same material with a pattern.
    pub fn with_pattern(self, pattern: Pattern) -> Self {
        Material { pattern, ..self }
    }

    /// Multiplies the albedo by a factor per channel.
    pub fn tinted(self, tint: [f32; 3]) -> Self {
        let mut albedo = self.albedo;
        for (a, t) in albedo.iter_mut().zip(tint) {
            *a = (*a * t).clamp(0.0, 1.0);
        }
        Material { albedo, ..self }
    }

    /// The pattern's brightness factor at a mesh-frame point (around 1).
    #[inline]
    pub fn pattern_factor(&self, p: [f32; 3]) -> f32 {
        match self.pattern {
            Pattern::Solid => 1.0,
            Pattern::Weave { period_m, contrast } => {
                let u = fract(p[0] / period_m);
                let v = fract(p[1] / period_m);
                // Distance to the nearest thread centre line in each direction.
                let du = (u - 0.5).abs() * 2.0;
                let dv = (v - 0.5).abs() * 2.0;
                let thread = du.min(dv);
                1.0 - contrast * thread * thread
            }
            Pattern::Mottled {
                scale_m,
                contrast,
                seed,
            } => {
                let s = 1.0 / scale_m;
                1.0 + contrast * value_noise2([p[0] * s, p[1] * s], seed)
            }
            Pattern::Brushed { period_m, contrast } => {
                let u = fract(p[0] / period_m);
                1.0 - contrast * (u - 0.5).abs()
            }
        }
    }
}

/// sRGB byte to linear.
pub fn srgb_to_linear(value: u8) -> f32 {
    let c = f32::from(value) / 255.0;
    if c <= 0.04045 {
        c / 12.92
    } else {
        ((c + 0.055) / 1.055).powf(2.4)
    }
}

/// Linear [0, 1] to an sRGB byte.
pub fn linear_to_srgb(value: f32) -> u8 {
    let c = value.clamp(0.0, 1.0);
    let s = if c <= 0.003_130_8 {
        c * 12.92
    } else {
        1.055 * c.powf(1.0 / 2.4) - 0.055
    };
    (s * 255.0 + 0.5) as u8
}

const SRGB_LUT_SIZE: usize = 16384;

/// A table from linear [0, 1] to sRGB bytes (the per-pixel path).
pub struct SrgbTable([u8; SRGB_LUT_SIZE]);

impl SrgbTable {
    /// The byte for a linear value (negative and NaN read as 0, above 1 as 1).
    #[inline]
    #[allow(clippy::manual_clamp)] // `max` then `min` maps NaN to 0; `clamp` would keep it NaN.
    pub fn lookup(&self, value: f32) -> u8 {
        // Adding 2^23 puts round(x) in the low mantissa bits for 0 <= x < 2^23: a conversion
        // without the saturating float-to-integer cast.
        let scaled = value.max(0.0).min(1.0) * (SRGB_LUT_SIZE - 1) as f32 + 8_388_608.0;
        self.0[(scaled.to_bits() as usize) & (SRGB_LUT_SIZE - 1)]
    }
}

/// The shared sRGB table, built on first use.
pub fn srgb_table() -> &'static SrgbTable {
    static LUT: std::sync::OnceLock<Box<SrgbTable>> = std::sync::OnceLock::new();
    LUT.get_or_init(|| {
        let mut table = Box::new(SrgbTable([0u8; SRGB_LUT_SIZE]));
        for (i, entry) in table.0.iter_mut().enumerate() {
            *entry = linear_to_srgb(i as f32 / (SRGB_LUT_SIZE - 1) as f32);
        }
        table
    })
}

/// The 3-D two-octave mottling factor of `pattern` at `p` (1 for other patterns): what
/// [`crate::render::mesh::Mesh::bake`] stores per vertex.
pub fn mottling3(pattern: &Pattern, p: [f32; 3]) -> f32 {
    match *pattern {
        Pattern::Mottled {
            scale_m,
            contrast,
            seed,
        } => {
            let s = 1.0 / scale_m;
            let n = value_noise3([p[0] * s, p[1] * s, p[2] * s], seed) * 0.65
                + value_noise3(
                    [p[0] * s * 2.7, p[1] * s * 2.7, p[2] * s * 2.7],
                    seed ^ 0x9e37,
                ) * 0.35;
            1.0 + contrast * n
        }
        _ => 1.0,
    }
}

/// The fractional part in [0, 1).
#[inline]
fn fract(x: f32) -> f32 {
    x - floor_i32(x) as f32
}

/// Smooth 2-D value noise in [-1, 1] with unit lattice spacing.
#[inline]
pub fn value_noise2(p: [f32; 2], seed: u32) -> f32 {
    let (x, y) = (floor_i32(p[0]), floor_i32(p[1]));
    let (fx, fy) = (p[0] - x as f32, p[1] - y as f32);
    let sx = fx * fx * (3.0 - 2.0 * fx);
    let sy = fy * fy * (3.0 - 2.0 * fy);
    let h = |dx: i32, dy: i32| lattice_hash(x + dx, y + dy, 0, seed);
    let top = h(0, 0) + (h(1, 0) - h(0, 0)) * sx;
    let bottom = h(0, 1) + (h(1, 1) - h(0, 1)) * sx;
    top + (bottom - top) * sy
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn srgb_round_trips_every_byte() {
        for b in 0..=255u8 {
            assert_eq!(linear_to_srgb(srgb_to_linear(b)), b);
        }
    }

    #[test]
    fn noise_is_bounded_smooth_and_seeded() {
        let mut previous = value_noise3([0.0, 0.3, 0.7], 1);
        for i in 1..1000 {
            let t = i as f32 * 0.01;
            let n = value_noise3([t, 0.3, 0.7], 1);
            assert!((-1.0..=1.0).contains(&n));
            assert!((n - previous).abs() < 0.05, "jump at {t}");
            previous = n;
        }
        assert_ne!(
            value_noise3([0.5, 0.5, 0.5], 1),
            value_noise3([0.5, 0.5, 0.5], 2)
        );
    }

    #[test]
    fn table_maps_out_of_range_and_nan_to_the_ends() {
        let table = srgb_table();
        assert_eq!(table.lookup(f32::NAN), 0);
        assert_eq!(table.lookup(-3.0), 0);
        assert_eq!(table.lookup(7.0), 255);
        assert_eq!(table.lookup(1.0), 255);
    }

    #[test]
    fn table_conversion_is_within_one_level() {
        for i in 0..=1000 {
            let v = i as f32 / 1000.0;
            assert!(i16::from(srgb_table().lookup(v)).abs_diff(i16::from(linear_to_srgb(v))) <= 1);
        }
    }
}

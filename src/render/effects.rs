//! Image-space effects applied to a rendered frame's RGB (never to depth or mask): the
//! endoscope light's colour and an off-axis fall-off across the view, smoke (a haze blended
//! over the scene), blood pooled on chosen mask classes, a box blur and sensor noise.
//!
//! The evaluation's visual perturbations draw them ([`crate::eval::perturb`]); the neutral
//! [`ImageEffects::default`] changes nothing and costs nothing. Everything is a pure function
//! of the effect's numbers, the frame and the frame's index, so a perturbed trial renders the
//! same bytes on every machine.

use super::material::{srgb_table, srgb_to_linear};
use super::raster::Frame;
use crate::noise::value_noise3;
use crate::rng::SplitMix64;

/// What to do to each frame.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct ImageEffects {
    /// Multiplies the linear light per channel (the light's colour; 1 = white).
    pub light_tint: [f32; 3],
    /// The light falls off across the view: factor `1 + slope . p`, `p` the pixel's position
    /// with the image spanning -1..1 in x (right) and y (down).
    pub light_slope: [f32; 2],
    /// Fraction of smoke blended over every pixel (0 = clear).
    pub haze: f32,
    /// Fraction of the `blood_classes` pixels covered by blood (0 = none).
    pub blood_coverage: f32,
    /// Mask ids (bit i = id i, ids below 32) blood may cover.
    pub blood_classes: u32,
    /// Where the blood pools (noise seed).
    pub blood_seed: u32,
    /// Box blur radius, pixels (0 = sharp).
    pub blur_radius_px: u32,
    /// Standard deviation of the sensor noise, in 8-bit levels (0 = none).
    pub noise_sigma: f32,
    /// Seeds the noise; each frame draws its own from it and the frame's index.
    pub noise_seed: u64,
}

impl Default for ImageEffects {
    fn default() -> Self {
        ImageEffects {
            light_tint: [1.0; 3],
            light_slope: [0.0; 2],
            haze: 0.0,
            blood_coverage: 0.0,
            blood_classes: 0,
            blood_seed: 0,
            blur_radius_px: 0,
            noise_sigma: 0.0,
            noise_seed: 0,
        }
    }
}

/// The smoke's colour, linear RGB (a warm grey, lit by the endoscope).
const SMOKE: [f32; 3] = [0.62, 0.6, 0.56];
/// Clotted blood, linear RGB.
const BLOOD: [f32; 3] = [0.16, 0.004, 0.006];
/// Blood pools' feature size, pixels.
const BLOOD_SCALE_PX: f32 = 18.0;

impl ImageEffects {
    /// Whether the effects leave a frame as it is.
    pub fn is_identity(&self) -> bool {
        *self == ImageEffects::default()
    }

    /// Applies the effects to `frame`'s RGB, `index` being its frame number in the episode
    /// (the sensor noise differs from frame to frame, reproducibly).
    pub fn apply(&self, frame: &mut Frame, index: u64) {
        if self.is_identity() {
            return;
        }
        let (w, h) = (frame.width_px as usize, frame.height_px as usize);
        if frame.rgb.len() != w * h * 3 {
            return;
        }
        if self.needs_linear() {
            self.light(frame, w, h);
        }
        if self.blur_radius_px > 0 {
            box_blur(&mut frame.rgb, w, h, self.blur_radius_px as usize);
        }
        if self.noise_sigma > 0.0 {
            let mut rng = SplitMix64::stream(self.noise_seed ^ index, "sensor-noise");
            for v in &mut frame.rgb {
                let n = gaussian(&mut rng) * self.noise_sigma;
                *v = (f32::from(*v) + n).round().clamp(0.0, 255.0) as u8;
            }
        }
    }

    fn needs_linear(&self) -> bool {
        self.light_tint != [1.0; 3]
            || self.light_slope != [0.0; 2]
            || self.haze > 0.0
            || self.blood_coverage > 0.0
    }

    /// The light's colour and fall-off, blood and smoke, in linear light.
    fn light(&self, frame: &mut Frame, w: usize, h: usize) {
        let table = srgb_table();
        let linear: Vec<f32> = (0..=255u8).map(srgb_to_linear).collect();
        let mask_ok = frame.mask.len() == w * h;
        let pools = |x: usize, y: usize| {
            let scale = BLOOD_SCALE_PX;
            value_noise3([x as f32 / scale, y as f32 / scale, 0.5], self.blood_seed)
        };
        // Blood covers a pixel where the pools' noise is above the quantile that leaves the
        // coverage's fraction of the image above it.
        let threshold = if self.blood_coverage > 0.0 && mask_ok {
            let mut noise: Vec<f32> = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| pools(x, y))
                .collect();
            let rank = ((1.0 - self.blood_coverage.clamp(0.0, 1.0)) * noise.len() as f32) as usize;
            let rank = rank.min(noise.len().saturating_sub(1));
            *noise.select_nth_unstable_by(rank, f32::total_cmp).1
        } else {
            f32::INFINITY
        };
        for y in 0..h {
            let py = (2.0 * (y as f32 + 0.5) / h as f32) - 1.0;
            for x in 0..w {
                let px = (2.0 * (x as f32 + 0.5) / w as f32) - 1.0;
                let i = y * w + x;
                let falloff = (1.0 + self.light_slope[0] * px + self.light_slope[1] * py).max(0.05);
                let bleeding = threshold.is_finite()
                    && frame.mask[i] < 32
                    && self.blood_classes & (1 << frame.mask[i]) != 0
                    && pools(x, y) > threshold;
                for c in 0..3 {
                    let mut v = linear[usize::from(frame.rgb[i * 3 + c])];
                    if bleeding {
                        // Blood is dark and wet: mostly its own colour, a little of the light.
                        v = BLOOD[c] + 0.15 * v;
                    }
                    v *= self.light_tint[c] * falloff;
                    v = v * (1.0 - self.haze) + SMOKE[c] * self.haze;
                    frame.rgb[i * 3 + c] = table.lookup(v);
                }
            }
        }
    }
}

/// A standard normal draw (Box-Muller).
fn gaussian(rng: &mut SplitMix64) -> f32 {
    let u1 = rng.next_f64().max(1e-12);
    let u2 = rng.next_f64();
    ((-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()) as f32
}

/// A separable box blur of radius `r` (clamped at the borders), in place.
fn box_blur(rgb: &mut [u8], w: usize, h: usize, r: usize) {
    let mut line = Vec::new();
    let mut pass =
        |rgb: &mut [u8], len: usize, count: usize, at: &dyn Fn(usize, usize) -> usize| {
            for k in 0..count {
                line.clear();
                line.extend((0..len).flat_map(|j| {
                    let i = at(k, j);
                    [rgb[i], rgb[i + 1], rgb[i + 2]]
                }));
                for j in 0..len {
                    let (lo, hi) = (j.saturating_sub(r), (j + r).min(len - 1));
                    let n = (hi - lo + 1) as u32;
                    let i = at(k, j);
                    for c in 0..3 {
                        let sum: u32 = (lo..=hi).map(|m| u32::from(line[m * 3 + c])).sum();
                        rgb[i + c] = ((sum + n / 2) / n) as u8;
                    }
                }
            }
        };
    pass(rgb, w, h, &|row, col| (row * w + col) * 3);
    pass(rgb, h, w, &|col, row| (row * w + col) * 3);
}

#[cfg(test)]
mod tests {
    use super::*;

    fn frame(rgb: Vec<u8>, mask: Vec<u8>, w: u32, h: u32) -> Frame {
        Frame {
            width_px: w,
            height_px: h,
            depth_m: vec![0.1; (w * h) as usize],
            rgb,
            mask,
        }
    }

    fn checker(w: u32, h: u32) -> Frame {
        let rgb = (0..w * h)
            .flat_map(|i| {
                let v = if (i % w + i / w).is_multiple_of(2) {
                    40
                } else {
                    200
                };
                [v, v, v]
            })
            .collect();
        frame(rgb, vec![2; (w * h) as usize], w, h)
    }

    #[test]
    fn the_neutral_effects_change_nothing() {
        let mut f = checker(16, 12);
        let before = f.clone();
        ImageEffects::default().apply(&mut f, 3);
        assert_eq!(f, before);
    }

    #[test]
    fn each_effect_does_what_it_says() {
        let mean = |f: &Frame, c: usize| -> f64 {
            f.rgb
                .iter()
                .skip(c)
                .step_by(3)
                .map(|&v| f64::from(v))
                .sum::<f64>()
                / (f.rgb.len() / 3) as f64
        };
        let spread = |f: &Frame| -> f64 {
            let m = mean(f, 0);
            f.rgb.iter().map(|&v| (f64::from(v) - m).abs()).sum::<f64>() / f.rgb.len() as f64
        };
        let base = checker(32, 32);
        let with = |e: ImageEffects| {
            let mut f = base.clone();
            e.apply(&mut f, 0);
            f
        };
        let warm = with(ImageEffects {
            light_tint: [1.2, 1.0, 0.8],
            ..ImageEffects::default()
        });
        assert!(mean(&warm, 0) > mean(&base, 0) && mean(&warm, 2) < mean(&base, 2));
        let sloped = with(ImageEffects {
            light_slope: [0.5, 0.0],
            ..ImageEffects::default()
        });
        let left: u32 = (0..32).map(|y| u32::from(sloped.rgb[y * 96])).sum();
        let right: u32 = (0..32).map(|y| u32::from(sloped.rgb[y * 96 + 93])).sum();
        assert!(right > left + 32 * 20, "{left} {right}");
        let smoky = with(ImageEffects {
            haze: 0.4,
            ..ImageEffects::default()
        });
        assert!(spread(&smoky) < 0.8 * spread(&base));
        let blurred = with(ImageEffects {
            blur_radius_px: 1,
            ..ImageEffects::default()
        });
        assert!(spread(&blurred) < 0.5 * spread(&base));
        let bloody = with(ImageEffects {
            blood_coverage: 0.3,
            blood_classes: 1 << 2,
            blood_seed: 5,
            ..ImageEffects::default()
        });
        let red = (0..32 * 32)
            .filter(|i| bloody.rgb[i * 3] > 2 * bloody.rgb[i * 3 + 1] + 10)
            .count();
        assert!((80..700).contains(&red), "{red} of 1024 pixels are blood");
        // Blood only where the classes are.
        let elsewhere = with(ImageEffects {
            blood_coverage: 0.3,
            blood_classes: 1 << 9,
            blood_seed: 5,
            ..ImageEffects::default()
        });
        assert_eq!(elsewhere, base);
        let noisy = |index| {
            let mut f = base.clone();
            let e = ImageEffects {
                noise_sigma: 6.0,
                noise_seed: 11,
                ..ImageEffects::default()
            };
            e.apply(&mut f, index);
            f
        };
        assert_eq!(noisy(1), noisy(1));
        assert_ne!(noisy(1), noisy(2));
        let changed = noisy(1)
            .rgb
            .iter()
            .zip(&base.rgb)
            .filter(|(a, b)| a != b)
            .count();
        assert!(changed > base.rgb.len() / 2);
    }
}

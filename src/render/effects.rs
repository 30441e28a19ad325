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
    /// (the sensor noise differs from frame to frame, reproducibly). `cache` keeps what stays
    /// the same from frame to frame of an episode (where blood pools, the noise's table).
    pub fn apply(&self, frame: &mut Frame, index: u64, cache: &mut EffectsCache) {
        if self.is_identity() {
            return;
        }
        let (w, h) = (frame.width_px as usize, frame.height_px as usize);
        if frame.rgb.len() != w * h * 3 {
            return;
        }
        if self.needs_linear() {
            let pooled = cache.pools(self, w, h);
            self.light(frame, w, h, pooled);
        }
        if self.blur_radius_px > 0 {
            box_blur(&mut frame.rgb, w, h, self.blur_radius_px as usize);
        }
        if self.noise_sigma > 0.0 {
            // Four draws from the episode's table of noise values per 64-bit draw.
            let table = cache.noise(self);
            let mut rng = SplitMix64::stream(self.noise_seed ^ index, "sensor-noise");
            for values in frame.rgb.chunks_mut(4) {
                let bits = rng.next_u64();
                for (k, v) in values.iter_mut().enumerate() {
                    let n = table[((bits >> (16 * k)) & 0xffff) as usize];
                    *v = (i16::from(*v) + n).clamp(0, 255) as u8;
                }
            }
        }
    }

    fn needs_linear(&self) -> bool {
        self.light_tint != [1.0; 3]
            || self.light_slope != [0.0; 2]
            || self.haze > 0.0
            || self.blood_coverage > 0.0
    }

    /// The light's colour and fall-off, blood and smoke, in linear light; `pools` marks where
    /// blood lies (where the mask allows it).
    fn light(&self, frame: &mut Frame, w: usize, h: usize, pools: &[bool]) {
        let table = srgb_table();
        let linear: Vec<f32> = (0..=255u8).map(srgb_to_linear).collect();
        if self.light_slope == [0.0; 2] && pools.is_empty() {
            // The same for every pixel: one table per channel.
            let maps: [Vec<u8>; 3] = std::array::from_fn(|c| {
                (linear.iter())
                    .map(|v| {
                        let v = v * self.light_tint[c];
                        table.lookup(v * (1.0 - self.haze) + SMOKE[c] * self.haze)
                    })
                    .collect()
            });
            for pixel in frame.rgb.chunks_exact_mut(3) {
                for c in 0..3 {
                    pixel[c] = maps[c][usize::from(pixel[c])];
                }
            }
            return;
        }
        let mask_ok = frame.mask.len() == w * h && pools.len() == w * h;
        for y in 0..h {
            let py = (2.0 * (y as f32 + 0.5) / h as f32) - 1.0;
            for x in 0..w {
                let px = (2.0 * (x as f32 + 0.5) / w as f32) - 1.0;
                let i = y * w + x;
                let falloff = (1.0 + self.light_slope[0] * px + self.light_slope[1] * py).max(0.05);
                let bleeding = mask_ok
                    && pools[i]
                    && frame.mask[i] < 32
                    && self.blood_classes & (1 << frame.mask[i]) != 0;
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

/// What the effects keep from frame to frame of an episode: where blood pools in frames of one
/// size (the pixels whose pools' noise lies above the quantile that leaves the coverage's
/// fraction of the image above it), and 65,536 noise values (rounded, in 8-bit levels) that
/// every frame draws from.
#[derive(Clone, Debug, Default)]
pub struct EffectsCache {
    /// (width, height, seed, coverage bits) and the map.
    key: Option<(usize, usize, u32, u32)>,
    map: Vec<bool>,
    /// (seed, sigma bits) and the table.
    noise_key: Option<(u64, u32)>,
    noise: Vec<i16>,
}

impl EffectsCache {
    fn noise(&mut self, effects: &ImageEffects) -> &[i16] {
        let key = (effects.noise_seed, effects.noise_sigma.to_bits());
        if self.noise_key != Some(key) {
            let mut rng = SplitMix64::stream(effects.noise_seed, "sensor-noise table");
            self.noise = (0..1 << 16)
                .map(|_| (normal(&mut rng) * effects.noise_sigma).round() as i16)
                .collect();
            self.noise_key = Some(key);
        }
        &self.noise
    }

    fn pools(&mut self, effects: &ImageEffects, w: usize, h: usize) -> &[bool] {
        if effects.blood_coverage <= 0.0 {
            return &[];
        }
        let key = (w, h, effects.blood_seed, effects.blood_coverage.to_bits());
        if self.key != Some(key) {
            let noise: Vec<f32> = (0..h)
                .flat_map(|y| (0..w).map(move |x| (x, y)))
                .map(|(x, y)| {
                    let scale = BLOOD_SCALE_PX;
                    value_noise3(
                        [x as f32 / scale, y as f32 / scale, 0.5],
                        effects.blood_seed,
                    )
                })
                .collect();
            let mut sorted = noise.clone();
            let coverage = effects.blood_coverage.clamp(0.0, 1.0);
            let rank = ((1.0 - coverage) * sorted.len() as f32) as usize;
            let rank = rank.min(sorted.len().saturating_sub(1));
            let threshold = *sorted.select_nth_unstable_by(rank, f32::total_cmp).1;
            self.map = noise.iter().map(|&n| n > threshold).collect();
            self.key = Some(key);
        }
        &self.map
    }
}

/// An approximately standard normal draw: the sum of four uniforms (Irwin-Hall) from one
/// 64-bit draw, centred and scaled to unit variance (tails end at 3.5 sigma).
fn normal(rng: &mut SplitMix64) -> f32 {
    let bits = rng.next_u64();
    let sum: f32 = (0..4)
        .map(|k| f32::from((bits >> (16 * k)) as u16) / 65_535.0)
        .sum();
    (sum - 2.0) * 3f32.sqrt()
}

/// A separable box blur of radius `r` (the window clamped at the borders), in place: running
/// sums along each row, then down the columns, a row at a time.
fn box_blur(rgb: &mut [u8], w: usize, h: usize, r: usize) {
    if w == 0 || h == 0 {
        return;
    }
    let window = |j: usize, len: usize| ((j + r).min(len - 1) - j.saturating_sub(r) + 1) as u32;
    let mut line: Vec<u32> = Vec::with_capacity(w * 3);
    for row in rgb.chunks_exact_mut(w * 3) {
        line.clear();
        line.extend(row.iter().map(|&v| u32::from(v)));
        let mut sum = [0u32; 3];
        for x in 0..=r.min(w - 1) {
            for c in 0..3 {
                sum[c] += line[x * 3 + c];
            }
        }
        for x in 0..w {
            let n = window(x, w);
            for c in 0..3 {
                row[x * 3 + c] = ((sum[c] + n / 2) / n) as u8;
                if x + r + 1 < w {
                    sum[c] += line[(x + r + 1) * 3 + c];
                }
                if x >= r {
                    sum[c] -= line[(x - r) * 3 + c];
                }
            }
        }
    }
    let rows: Vec<u32> = rgb.iter().map(|&v| u32::from(v)).collect();
    let stride = w * 3;
    let mut sums = vec![0u32; stride];
    for y in 0..=r.min(h - 1) {
        for (s, v) in sums.iter_mut().zip(&rows[y * stride..(y + 1) * stride]) {
            *s += v;
        }
    }
    for y in 0..h {
        let n = window(y, h);
        for (out, s) in rgb[y * stride..(y + 1) * stride].iter_mut().zip(&sums) {
            *out = ((s + n / 2) / n) as u8;
        }
        if y + r + 1 < h {
            let entering = &rows[(y + r + 1) * stride..(y + r + 2) * stride];
            for (s, v) in sums.iter_mut().zip(entering) {
                *s += v;
            }
        }
        if y >= r {
            let leaving = &rows[(y - r) * stride..(y - r + 1) * stride];
            for (s, v) in sums.iter_mut().zip(leaving) {
                *s -= v;
            }
        }
    }
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

    /// The running sums give what averaging each clamped window does.
    #[test]
    fn the_blur_is_the_mean_of_each_clamped_window() {
        let (w, h, r) = (9usize, 7usize, 2usize);
        let mut rng = SplitMix64::new(3);
        let original: Vec<u8> = (0..w * h * 3).map(|_| rng.next_u64() as u8).collect();
        let mut blurred = original.clone();
        box_blur(&mut blurred, w, h, r);
        let mean = |values: &mut dyn Iterator<Item = u32>| {
            let v: Vec<u32> = values.collect();
            ((v.iter().sum::<u32>() + v.len() as u32 / 2) / v.len() as u32) as u8
        };
        let span = |j: usize, len: usize| j.saturating_sub(r)..=(j + r).min(len - 1);
        let mut rows = original.clone();
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let at = |x: usize| u32::from(original[(y * w + x) * 3 + c]);
                    rows[(y * w + x) * 3 + c] = mean(&mut span(x, w).map(at));
                }
            }
        }
        for y in 0..h {
            for x in 0..w {
                for c in 0..3 {
                    let at = |y: usize| u32::from(rows[(y * w + x) * 3 + c]);
                    assert_eq!(blurred[(y * w + x) * 3 + c], mean(&mut span(y, h).map(at)));
                }
            }
        }
    }

    #[test]
    fn the_neutral_effects_change_nothing() {
        let mut f = checker(16, 12);
        let before = f.clone();
        ImageEffects::default().apply(&mut f, 3, &mut EffectsCache::default());
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
            e.apply(&mut f, 0, &mut EffectsCache::default());
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
            e.apply(&mut f, index, &mut EffectsCache::default());
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

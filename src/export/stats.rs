//! Feature statistics in LeRobot's shape: min, max, mean, std, count and the q01, q10, q50, q90,
//! q99 quantiles, per vector element or per image channel.
//!
//! Memory stays bounded: sums are running, vector quantiles come from a deterministic reservoir
//! of at most [`RESERVOIR`] values per element (exact below that), and image quantiles from
//! per-channel histograms (256 bins for u8 channels, [`DEPTH_BINS`] over 0..`DEPTH_RANGE_M` for
//! depth).

use crate::rng::SplitMix64;

mod stated;
mod stored;
use serde_json::Value;
pub use stated::{MOMENTS, Stated};

/// Values kept per vector element for quantiles: full after a few hundred episodes, so peak
/// memory (and a checkpoint's size) stays flat in episodes; q01's rank error from such a sample
/// is about 0.1 %.
pub const RESERVOIR: usize = 10_000;
/// Histogram bins for depth quantiles and their range, metres.
pub const DEPTH_BINS: usize = 8192;
pub const DEPTH_RANGE_M: f64 = 0.5;
/// Lanes a depth frame's sums run in (see [`ImageStats::push_depth_counting`]).
const DEPTH_LANES: usize = 4;
/// The quantiles LeRobot (and pi0.5-style normalisation) reads.
pub const QUANTILES: [(&str, f64); 5] = [
    ("q01", 0.01),
    ("q10", 0.10),
    ("q50", 0.50),
    ("q90", 0.90),
    ("q99", 0.99),
];

/// Bins of a u8 channel's histogram, and their width once scaled to [0, 1].
const U8_BINS: usize = 256;
const U8_BIN_WIDTH: f64 = 1.0 / 255.0;
/// The width of a depth histogram's bins, metres.
const DEPTH_BIN_WIDTH_M: f64 = DEPTH_RANGE_M / DEPTH_BINS as f64;

/// (channels, bins per channel, bin width) of image feature `feature`'s statistics: u8
/// channels scaled to [0, 1] (RGB, masks, another dataset's images), or depth in metres; None
/// for a feature that is not an image.
fn image_shape(feature: &crate::episode::FeatureSpec) -> Option<(usize, usize, f64)> {
    use crate::episode::{Dtype, FeatureKind};
    match feature.kind {
        FeatureKind::Rgb => Some((3, U8_BINS, U8_BIN_WIDTH)),
        FeatureKind::Mask => Some((1, U8_BINS, U8_BIN_WIDTH)),
        FeatureKind::Depth => Some((1, DEPTH_BINS, DEPTH_BIN_WIDTH_M)),
        FeatureKind::Other if feature.dtype == Dtype::Image => Some((
            feature.shape.get(2).copied().unwrap_or(1),
            U8_BINS,
            U8_BIN_WIDTH,
        )),
        _ => None,
    }
}

/// Running statistics of one scalar series (in a checkpoint, a value JSON cannot hold, such as
/// an empty series' infinite minimum or a NaN in the data, is written as text).
#[derive(serde::Serialize, serde::Deserialize, Clone, Copy, Debug)]
struct Running {
    count: u64,
    #[serde(with = "stored::any_f64")]
    sum: f64,
    #[serde(with = "stored::any_f64")]
    sum_sq: f64,
    #[serde(with = "stored::any_f64")]
    min: f64,
    #[serde(with = "stored::any_f64")]
    max: f64,
}

impl Default for Running {
    fn default() -> Self {
        Running {
            count: 0,
            sum: 0.0,
            sum_sq: 0.0,
            min: f64::INFINITY,
            max: f64::NEG_INFINITY,
        }
    }
}

impl Running {
    fn push(&mut self, v: f64) {
        self.count += 1;
        self.sum += v;
        self.sum_sq += v * v;
        self.min = self.min.min(v);
        self.max = self.max.max(v);
    }

    fn merge(&mut self, other: &Running) {
        self.count += other.count;
        self.sum += other.sum;
        self.sum_sq += other.sum_sq;
        self.min = self.min.min(other.min);
        self.max = self.max.max(other.max);
    }

    fn mean(&self) -> f64 {
        if self.count == 0 {
            0.0
        } else {
            self.sum / self.count as f64
        }
    }

    fn std(&self) -> f64 {
        if self.count == 0 {
            return 0.0;
        }
        let mean = self.mean();
        (self.sum_sq / self.count as f64 - mean * mean)
            .max(0.0)
            .sqrt()
    }

    fn finite_min(&self) -> f64 {
        if self.count == 0 { 0.0 } else { self.min }
    }

    fn finite_max(&self) -> f64 {
        if self.count == 0 { 0.0 } else { self.max }
    }
}

/// Statistics of a vector feature, per element.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
pub struct VectorStats {
    running: Vec<Running>,
    #[serde(with = "stored::f32_bits")]
    reservoirs: Vec<Vec<f32>>,
    seen: u64,
    rng: SplitMix64,
}

fn quantile_sorted(sorted: &[f32], q: f64) -> f64 {
    if sorted.is_empty() {
        return 0.0;
    }
    // Linear interpolation between closest ranks (numpy's default).
    let position = q * (sorted.len() - 1) as f64;
    let low = position.floor() as usize;
    let high = (low + 1).min(sorted.len() - 1);
    let t = position - low as f64;
    f64::from(sorted[low]) * (1.0 - t) + f64::from(sorted[high]) * t
}

impl VectorStats {
    pub fn new(len: usize) -> Self {
        VectorStats {
            running: vec![Running::default(); len],
            reservoirs: vec![Vec::new(); len],
            seen: 0,
            rng: SplitMix64::stream(0, "stats reservoir"),
        }
    }

    /// Makes room for `frames` more frames' values (as many as the reservoir takes).
    pub fn reserve(&mut self, frames: usize) {
        let room = RESERVOIR.saturating_sub(self.seen as usize).min(frames);
        for reservoir in &mut self.reservoirs {
            reservoir.reserve(room);
        }
    }

    /// Elements per value.
    pub fn elements(&self) -> usize {
        self.running.len()
    }

    /// Adds one frame's vector.
    pub fn push(&mut self, values: &[f32]) {
        for (running, v) in self.running.iter_mut().zip(values) {
            running.push(f64::from(*v));
        }
        self.sample(values.iter().copied());
    }

    /// Adds one frame's float64 vector (another tool's): the running statistics in float64,
    /// the quantiles' sample in float32.
    pub fn push_f64(&mut self, values: &[f64]) {
        for (running, v) in self.running.iter_mut().zip(values) {
            running.push(*v);
        }
        self.sample(values.iter().map(|&v| v as f32));
    }

    /// Folds in another series' statistics (its sampled values join the reservoir).
    pub fn merge(&mut self, other: &VectorStats) {
        for (a, b) in self.running.iter_mut().zip(&other.running) {
            a.merge(b);
        }
        let rows = other.reservoirs.first().map_or(0, Vec::len);
        for row in 0..rows {
            // (Rows of equal length unless a checkpoint was altered: a short one is passed.)
            self.sample(other.reservoirs.iter().filter_map(|r| r.get(row).copied()));
        }
    }

    /// Reservoir sampling of one frame's values (algorithm R, seeded).
    fn sample(&mut self, values: impl Iterator<Item = f32>) {
        self.seen += 1;
        let slot = if self.seen as usize <= RESERVOIR {
            Some(self.seen as usize - 1)
        } else {
            let j = (self.rng.next_u64() % self.seen) as usize;
            (j < RESERVOIR).then_some(j)
        };
        for (i, v) in values.enumerate().take(self.reservoirs.len()) {
            let reservoir = &mut self.reservoirs[i];
            match slot {
                Some(s) if s == reservoir.len() => reservoir.push(v),
                Some(s) => {
                    // (Past the end only in a reservoir read from an altered checkpoint.)
                    if let Some(kept) = reservoir.get_mut(s) {
                        *kept = v;
                    }
                }
                None => {}
            }
        }
    }

    /// The statistics as LeRobot states them: each stat a list of per-element values.
    pub fn stated(&self) -> Stated {
        let per =
            |f: &dyn Fn(&Running) -> f64| -> Vec<f64> { self.running.iter().map(f).collect() };
        let sorted: Vec<Vec<f32>> = self
            .reservoirs
            .iter()
            .map(|r| {
                let mut s = r.clone();
                s.sort_unstable_by(f32::total_cmp);
                s
            })
            .collect();
        Stated {
            image: false,
            moments: [
                per(&|r| r.finite_min()),
                per(&|r| r.finite_max()),
                per(&|r| r.mean()),
                per(&|r| r.std()),
            ],
            count: self.seen,
            quantiles: (QUANTILES.iter())
                .map(|&(name, q)| (name, sorted.iter().map(|s| quantile_sorted(s, q)).collect()))
                .collect(),
        }
    }

    /// The statistics as LeRobot's JSON: each stat a list of per-element values.
    pub fn to_json(&self) -> Value {
        self.stated().to_json()
    }
}

/// Statistics of an image feature, per channel, from histograms ([`ImageCounts`]), with the
/// JSON they were read from when an episode carried them ([`ImageStats::carried`]), written
/// back as it was read ([`ImageStats::stored_json`]) until the counts change. Every change
/// goes through `DerefMut`, which forgets that JSON: no way of changing the counts can leave
/// it stale.
#[derive(Clone, Debug)]
pub struct ImageStats {
    counts: ImageCounts,
    /// The JSON text the counts were read from.
    stored: Option<String>,
}

/// An image feature's per-channel sums and histograms: what [`ImageStats`] holds and stores.
#[derive(serde::Serialize, serde::Deserialize, Clone, Debug)]
pub struct ImageCounts {
    running: Vec<Running>,
    /// Stored trimmed to the span of bins that count ([`stored::trimmed`]): a depth episode's 8,192
    /// bins are mostly empty.
    #[serde(with = "stored::trimmed")]
    histograms: Vec<Vec<u64>>,
    /// Value of bin `b` is `b * bin_width + offset` (u8 channels: b / 255).
    bin_width: f64,
    frames: u64,
}

impl std::ops::Deref for ImageStats {
    type Target = ImageCounts;

    fn deref(&self) -> &ImageCounts {
        &self.counts
    }
}

impl std::ops::DerefMut for ImageStats {
    /// The counts, to change: the JSON they were read from no longer says them.
    fn deref_mut(&mut self) -> &mut ImageCounts {
        self.stored = None;
        &mut self.counts
    }
}

impl From<ImageCounts> for ImageStats {
    fn from(counts: ImageCounts) -> Self {
        ImageStats {
            counts,
            stored: None,
        }
    }
}

impl serde::Serialize for ImageStats {
    fn serialize<S: serde::Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        self.counts.serialize(s)
    }
}

impl<'de> serde::Deserialize<'de> for ImageStats {
    fn deserialize<D: serde::Deserializer<'de>>(d: D) -> Result<Self, D::Error> {
        ImageCounts::deserialize(d).map(ImageStats::from)
    }
}

impl ImageStats {
    /// The statistics the JSON text `text` stores (an episode carrying them from its input),
    /// remembered with `text`, so that they are written back as they were read.
    pub fn carried(text: &str) -> Option<Self> {
        let counts = serde_json::from_str::<ImageCounts>(text).ok()?;
        Some(ImageStats {
            counts,
            stored: Some(text.to_owned()),
        })
    }

    /// The statistics as stored, as JSON text: the text they were read from if nothing changed
    /// them since.
    pub fn stored_json(&self) -> String {
        (self.stored.clone()).unwrap_or_else(|| {
            serde_json::to_string(&self.counts).unwrap_or_else(|_| "null".into())
        })
    }

    /// For u8 channels, reported scaled to [0, 1].
    pub fn unit_scaled(channels: usize) -> Self {
        ImageStats::empty(channels, U8_BINS, U8_BIN_WIDTH)
    }

    /// For depth in metres.
    pub fn depth() -> Self {
        ImageStats::empty(1, DEPTH_BINS, DEPTH_BIN_WIDTH_M)
    }

    /// No frame counted yet, in `channels` histograms of `bins` bins of `bin_width`.
    fn empty(channels: usize, bins: usize, bin_width: f64) -> Self {
        ImageStats::from(ImageCounts {
            running: vec![Running::default(); channels],
            histograms: vec![vec![0; bins]; channels],
            bin_width,
            frames: 0,
        })
    }
}

impl ImageCounts {
    /// Whether `other` has these statistics' channels, bins and bin width (merging it adds
    /// like to like).
    #[cfg(test)]
    pub fn same_shape(&self, other: &ImageCounts) -> bool {
        self.running.len() == other.running.len()
            && self.bin_width.to_bits() == other.bin_width.to_bits()
            && (self.histograms.iter().map(Vec::len)).eq(other.histograms.iter().map(Vec::len))
    }

    /// Whether these have the channels, bins and bin width of `feature`'s statistics
    /// ([`FeatureStats::for_feature`]'s, which this does not make: a depth feature's hold
    /// 8,192 bins).
    pub fn fits(&self, feature: &crate::episode::FeatureSpec) -> bool {
        image_shape(feature).is_some_and(|(channels, bins, bin_width)| {
            self.running.len() == channels
                && self.histograms.len() == channels
                && self.histograms.iter().all(|h| h.len() == bins)
                && self.bin_width.to_bits() == bin_width.to_bits()
        })
    }

    /// Folds in another image series' statistics.
    pub fn merge(&mut self, other: &ImageCounts) {
        self.frames += other.frames;
        for (a, b) in self.running.iter_mut().zip(&other.running) {
            a.merge(b);
        }
        for (a, b) in self.histograms.iter_mut().zip(&other.histograms) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }

    /// Adds one interleaved u8 image.
    pub fn push_u8(&mut self, pixels: &[u8]) {
        let mut histograms = std::mem::take(&mut self.histograms);
        self.push_u8_counting(pixels, &mut histograms);
        self.histograms = histograms;
    }

    /// Adds one depth image (metres).
    pub fn push_depth(&mut self, depth_m: &[f32]) {
        let mut histograms = std::mem::take(&mut self.histograms);
        self.push_depth_counting(depth_m, &mut histograms);
        self.histograms = histograms;
    }

    /// These statistics' shape without histograms: a frame's part whose pixel counts go to a
    /// histogram set kept elsewhere (see [`ImageStats::push_u8_counting`]). Merging it adds no
    /// counts.
    pub fn without_histograms(&self) -> ImageStats {
        ImageStats::from(ImageCounts {
            running: vec![Running::default(); self.running.len()],
            histograms: Vec::new(),
            bin_width: self.bin_width,
            frames: 0,
        })
    }

    /// Empty histograms of these statistics' shape.
    pub fn empty_histograms(&self) -> Vec<Vec<u64>> {
        self.histograms.iter().map(|h| vec![0; h.len()]).collect()
    }

    /// Adds `histograms` (of this shape) to these statistics' counts. Counts are integers, so
    /// the order parts are added in does not change them.
    pub fn add_histograms(&mut self, histograms: &[Vec<u64>]) {
        for (a, b) in self.histograms.iter_mut().zip(histograms) {
            for (x, y) in a.iter_mut().zip(b) {
                *x += y;
            }
        }
    }

    /// [`ImageStats::push_u8`] with the pixel counts going to `histograms` (one per channel).
    pub fn push_u8_counting(&mut self, pixels: &[u8], histograms: &mut [Vec<u64>]) {
        self.frames += 1;
        let channels = self.running.len();
        if channels == 0 {
            return;
        }
        let counts = count_u8(pixels, channels);
        self.fold_u8_counts(&counts, histograms);
    }

    /// [`ImageStats::push_depth_counting`] for the next frame of a series whose last frame
    /// `last` kept: the sums run over every pixel as there, the pixel counts are taken again
    /// only where blocks of pixels differ from the last frame's (integers: exactly a full
    /// count's).
    pub fn push_depth_counting_since(
        &mut self,
        depth_m: &[f32],
        histograms: &mut [Vec<u64>],
        last: &mut LastFrame,
    ) {
        let Some(counts) = histograms.first_mut().filter(|h| !h.is_empty()) else {
            return self.push_depth_counting(depth_m, histograms);
        };
        self.frames += 1;
        let scale = DepthBins::new(1.0 / self.bin_width, counts.len());
        let mut sums = DepthSums::default();
        let mut chunks = depth_m.chunks_exact(DEPTH_LANES);
        for chunk in &mut chunks {
            let mut values = [0f32; DEPTH_LANES];
            values.copy_from_slice(chunk);
            // The bins go unused (the compiler drops them): the sums are push_depth_counting's.
            sums.push(&values, &scale);
        }
        let rest = chunks.remainder();
        let mut values = [f32::NAN; DEPTH_LANES];
        values[..rest.len()].copy_from_slice(rest);
        sums.push_some(&values, rest.len(), &scale);
        let bins = counts.len();
        for (n, kept) in counts
            .iter_mut()
            .zip(last.depth_counts(depth_m, &scale, bins))
        {
            *n += u64::from(*kept);
        }
        if let Some(running) = self.running.first_mut() {
            running.merge(&sums.total(depth_m.len() as u64));
        }
    }

    /// [`ImageStats::push_u8_counting`] for the next frame of a series whose last frame
    /// `last` kept: only the blocks of pixels that differ from it are counted again (the
    /// counts are integers, so they are exactly those of a full count). Frames of a camera
    /// that stands still change where things move, a small part of each.
    pub fn push_u8_counting_since(
        &mut self,
        pixels: &[u8],
        histograms: &mut [Vec<u64>],
        last: &mut LastFrame,
    ) {
        self.frames += 1;
        let channels = self.running.len();
        if channels == 0 {
            return;
        }
        let counts = last.count(pixels, channels);
        self.fold_u8_counts(counts, histograms);
    }

    /// One frame's per-channel counts folded into the sums and added to `histograms`.
    fn fold_u8_counts(&mut self, counts: &[[u64; 256]], histograms: &mut [Vec<u64>]) {
        for (c, (counts, running)) in counts.iter().zip(self.running.iter_mut()).enumerate() {
            running.merge(&fold_counts(counts));
            if let Some(histogram) = histograms.get_mut(c) {
                for (bin, n) in histogram.iter_mut().zip(counts) {
                    *bin += n;
                }
            }
        }
    }

    /// [`ImageStats::push_depth`] with the pixel counts going to `histograms`.
    ///
    /// A frame's sums run in [`DEPTH_LANES`] lanes (pixel `i` into lane `i % DEPTH_LANES`),
    /// added up lane by lane in a fixed order: the same on every machine and for any thread
    /// count, and free of the one long chain of dependent additions a single sum makes (the
    /// compiler turns the lanes into vector instructions). The pixel counts go through as many
    /// tables taking turns, so a row of equal depths does not wait on one counter.
    pub fn push_depth_counting(&mut self, depth_m: &[f32], histograms: &mut [Vec<u64>]) {
        self.frames += 1;
        let counts = histograms.first_mut().filter(|h| !h.is_empty());
        let bins = counts.as_ref().map_or(1, |h| h.len());
        let scale = DepthBins::new(1.0 / self.bin_width, bins);
        let mut sums = DepthSums::default();
        let mut tables = vec![
            0u32;
            if counts.is_some() {
                bins * DEPTH_LANES
            } else {
                0
            }
        ];
        let mut chunks = depth_m.chunks_exact(DEPTH_LANES);
        for chunk in &mut chunks {
            let mut values = [0f32; DEPTH_LANES];
            values.copy_from_slice(chunk);
            let at = sums.push(&values, &scale);
            for (k, bin) in at.into_iter().enumerate() {
                if let Some(n) = tables.get_mut(bin as usize * DEPTH_LANES + k) {
                    *n += 1;
                }
            }
        }
        let rest = chunks.remainder();
        let mut values = [f32::NAN; DEPTH_LANES];
        values[..rest.len()].copy_from_slice(rest);
        let at = sums.push_some(&values, rest.len(), &scale);
        for bin in &at[..rest.len()] {
            if let Some(n) = tables.get_mut(*bin as usize * DEPTH_LANES) {
                *n += 1;
            }
        }
        if let Some(counts) = counts {
            for (n, lanes) in counts.iter_mut().zip(tables.chunks_exact(DEPTH_LANES)) {
                *n += lanes.iter().map(|t| u64::from(*t)).sum::<u64>();
            }
        }
        if let Some(running) = self.running.first_mut() {
            running.merge(&sums.total(depth_m.len() as u64));
        }
    }

    fn quantile(&self, channel: usize, q: f64) -> f64 {
        let histogram = &self.histograms[channel];
        let total: u64 = histogram.iter().sum();
        if total == 0 {
            return 0.0;
        }
        let target = (q * (total - 1) as f64).round() as u64;
        let mut cumulative = 0;
        for (bin, n) in histogram.iter().enumerate() {
            cumulative += n;
            if cumulative > target {
                return bin as f64 * self.bin_width;
            }
        }
        (histogram.len() - 1) as f64 * self.bin_width
    }

    /// The statistics as LeRobot states them: each stat per channel (nested (C, 1, 1));
    /// count = frames.
    pub fn stated(&self) -> Stated {
        let per = |f: &dyn Fn(usize, &Running) -> f64| -> Vec<f64> {
            (self.running.iter().enumerate())
                .map(|(c, r)| f(c, r))
                .collect()
        };
        Stated {
            image: true,
            moments: [
                per(&|_, r| r.finite_min()),
                per(&|_, r| r.finite_max()),
                per(&|_, r| r.mean()),
                per(&|_, r| r.std()),
            ],
            count: self.frames,
            quantiles: (QUANTILES.iter())
                .map(|&(name, q)| (name, per(&|c, _| self.quantile(c, q))))
                .collect(),
        }
    }

    /// The statistics as LeRobot's JSON: each stat a (C, 1, 1) nested list; count = frames.
    pub fn to_json(&self) -> Value {
        self.stated().to_json()
    }
}

/// A depth value's histogram bin, computed in `f32`: `trunc(x * per_bin + 0.5)` clamped to the
/// bins (negative and NaN values read as bin 0), without a libm call or a float-to-integer
/// conversion (neither becomes vector instructions).
///
/// With [`DEPTH_BINS`] over [`DEPTH_RANGE_M`], `per_bin` is 2^14, so `x * per_bin` is exact
/// and this is the same bin as the formula in `f64`, ties included (tested).
struct DepthBins {
    per_bin: f32,
    last: f32,
}

impl DepthBins {
    fn new(per_bin: f64, bins: usize) -> Self {
        DepthBins {
            per_bin: per_bin as f32,
            // The truncation below needs the bins under 2^22 (ours are 8,192).
            last: bins.saturating_sub(1).min(1 << 22) as f32,
        }
    }

    fn bin(&self, x: f32) -> i32 {
        // Plain comparisons, not `max` and `min`, so this stays a few vector instructions; a NaN
        // fails the first and reads as 0.
        let y = x * self.per_bin;
        let y = if y > 0.0 { y } else { 0.0 };
        let y = if y < self.last { y } else { self.last };
        // 0 <= y < 2^23: adding 2^23 rounds y to the nearest integer (ties to even), exactly
        // representable; a tie rounded down is one more for `trunc(y + 0.5)`.
        let nearest = (y + MAGIC) - MAGIC;
        let bin = if y - nearest == 0.5 {
            nearest + 1.0
        } else {
            nearest
        };
        ((bin + MAGIC).to_bits() & 0x7f_ffff) as i32
    }
}

/// 2^23, where an `f32`'s spacing is 1.
const MAGIC: f32 = 8_388_608.0;

/// A depth frame's sums in [`DEPTH_LANES`] lanes, one array per quantity.
struct DepthSums {
    sum: [f64; DEPTH_LANES],
    sum_sq: [f64; DEPTH_LANES],
    min: [f32; DEPTH_LANES],
    max: [f32; DEPTH_LANES],
}

impl Default for DepthSums {
    fn default() -> Self {
        DepthSums {
            sum: [0.0; DEPTH_LANES],
            sum_sq: [0.0; DEPTH_LANES],
            min: [f32::INFINITY; DEPTH_LANES],
            max: [f32::NEG_INFINITY; DEPTH_LANES],
        }
    }
}

impl DepthSums {
    /// Adds one value to each lane; returns their bins.
    #[inline(always)]
    fn push(&mut self, values: &[f32; DEPTH_LANES], bins: &DepthBins) -> [i32; DEPTH_LANES] {
        let mut at = [0i32; DEPTH_LANES];
        for k in 0..DEPTH_LANES {
            let v = values[k];
            let x = f64::from(v);
            self.sum[k] += x;
            self.sum_sq[k] += x * x;
            // Comparisons, not `min` and `max` (a NaN fails both and is left out alike).
            self.min[k] = if v < self.min[k] { v } else { self.min[k] };
            self.max[k] = if v > self.max[k] { v } else { self.max[k] };
            at[k] = bins.bin(v);
        }
        at
    }

    /// Adds the first `n` of `values` to lanes 0..n.
    fn push_some(
        &mut self,
        values: &[f32; DEPTH_LANES],
        n: usize,
        bins: &DepthBins,
    ) -> [i32; DEPTH_LANES] {
        let mut at = [0i32; DEPTH_LANES];
        for k in 0..n.min(DEPTH_LANES) {
            let mut one = DepthSums::default();
            let bin = one.push(&[values[k]; DEPTH_LANES], bins);
            self.sum[k] += one.sum[0];
            self.sum_sq[k] += one.sum_sq[0];
            self.min[k] = self.min[k].min(one.min[0]);
            self.max[k] = self.max[k].max(one.max[0]);
            at[k] = bin[0];
        }
        at
    }

    /// The lanes added up in lane order, over `count` values.
    fn total(&self, count: u64) -> Running {
        let mut frame = Running {
            count,
            ..Running::default()
        };
        for k in 0..DEPTH_LANES {
            frame.sum += self.sum[k];
            frame.sum_sq += self.sum_sq[k];
            frame.min = frame.min.min(f64::from(self.min[k]));
            frame.max = frame.max.max(f64::from(self.max[k]));
        }
        frame
    }
}

/// One u8 channel's running statistics (scaled to [0, 1]) from its value counts: sums over the
/// values in value order, so the same for any pixel order.
fn fold_counts(counts: &[u64; 256]) -> Running {
    let mut frame = Running::default();
    for (v, n) in counts.iter().enumerate().filter(|(_, n)| **n > 0) {
        let x = v as f64 / 255.0;
        frame.count += n;
        frame.sum += x * *n as f64;
        frame.sum_sq += x * x * *n as f64;
        frame.min = frame.min.min(x);
        frame.max = frame.max.max(x);
    }
    frame
}

/// The last frame an image series counted and its per-channel counts (see
/// [`ImageStats::push_u8_counting_since`]).
#[derive(Clone, Debug, Default)]
pub struct LastFrame {
    pixels: Vec<u8>,
    counts: Vec<[u64; 256]>,
    /// A depth series': the last frame's values (bits) and bin counts, and the bins'
    /// (scale bits, count).
    depth: Vec<u32>,
    depth_counts: Vec<u32>,
    depth_bins: Option<(u32, usize)>,
}

impl LastFrame {
    /// Pixels compared at a time: a block that differs is counted again.
    const BLOCK_PIXELS: usize = 32;

    /// The counts of `pixels` (a whole count for a first frame or a new size), kept with them
    /// for the next.
    fn count(&mut self, pixels: &[u8], channels: usize) -> &[[u64; 256]] {
        let pixels = &pixels[..pixels.len() - pixels.len() % channels];
        if self.counts.len() != channels || self.pixels.len() != pixels.len() {
            self.counts = count_u8(pixels, channels);
            self.pixels.clear();
            self.pixels.extend_from_slice(pixels);
            return &self.counts;
        }
        let block = channels * Self::BLOCK_PIXELS;
        for (kept, new) in self.pixels.chunks_mut(block).zip(pixels.chunks(block)) {
            if *kept == *new {
                continue;
            }
            for (was, now) in kept.chunks_exact(channels).zip(new.chunks_exact(channels)) {
                for ((counts, &was), &now) in self.counts.iter_mut().zip(was).zip(now) {
                    counts[usize::from(was)] -= 1;
                    counts[usize::from(now)] += 1;
                }
            }
            kept.copy_from_slice(new);
        }
        &self.counts
    }

    /// The bin counts of `depth_m` (a whole count for a first frame, a new size or new bins),
    /// kept with its values for the next.
    fn depth_counts(&mut self, depth_m: &[f32], scale: &DepthBins, bins: usize) -> &[u32] {
        let key = Some((scale.per_bin.to_bits(), bins));
        if self.depth_bins != key || self.depth.len() != depth_m.len() {
            self.depth_bins = key;
            self.depth_counts = vec![0; bins];
            for v in depth_m {
                if let Some(n) = self.depth_counts.get_mut(scale.bin(*v) as usize) {
                    *n += 1;
                }
            }
            self.depth.clear();
            self.depth.extend(depth_m.iter().map(|v| v.to_bits()));
            return &self.depth_counts;
        }
        let blocks = self.depth.chunks_mut(Self::BLOCK_PIXELS);
        for (kept, new) in blocks.zip(depth_m.chunks(Self::BLOCK_PIXELS)) {
            // Bits, not values: a NaN equals nothing, and -0 and 0 are different bits.
            let differ = kept
                .iter()
                .zip(new)
                .fold(0u32, |d, (was, now)| d | (was ^ now.to_bits()));
            if differ == 0 {
                continue;
            }
            // The block's bins before and after in one pass of vector instructions, then
            // counts moved where they differ.
            let mut before = [0i32; Self::BLOCK_PIXELS];
            let mut after = [0i32; Self::BLOCK_PIXELS];
            let bins = before.iter_mut().zip(&mut after);
            for ((b, a), (was, now)) in bins.zip(kept.iter().zip(new)) {
                *b = scale.bin(f32::from_bits(*was));
                *a = scale.bin(*now);
            }
            for (b, a) in before.iter().zip(&after).filter(|(b, a)| b != a) {
                if let Some(n) = self.depth_counts.get_mut(*b as usize) {
                    *n -= 1;
                }
                if let Some(n) = self.depth_counts.get_mut(*a as usize) {
                    *n += 1;
                }
            }
            for (was, now) in kept.iter_mut().zip(new) {
                *was = now.to_bits();
            }
        }
        &self.depth_counts
    }
}

/// Per channel, how many of the interleaved `pixels` hold each value. Four tables per channel
/// take turns, so runs of equal values (flat colour) do not wait on one counter.
fn count_u8(pixels: &[u8], channels: usize) -> Vec<[u64; 256]> {
    // A trailing partial pixel is left out.
    let pixels = &pixels[..pixels.len() - pixels.len() % channels];
    let mut tables = vec![[0u64; 256]; channels * 4];
    let group = channels * 4;
    let mut groups = pixels.chunks_exact(group);
    for chunk in &mut groups {
        for (table, v) in tables.iter_mut().zip(chunk) {
            table[usize::from(*v)] += 1;
        }
    }
    for (i, v) in groups.remainder().iter().enumerate() {
        tables[i][usize::from(*v)] += 1;
    }
    (0..channels)
        .map(|c| {
            let mut total = [0u64; 256];
            for k in 0..4 {
                for (t, n) in total.iter_mut().zip(&tables[k * channels + c]) {
                    *t += n;
                }
            }
            total
        })
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use serde_json::json;

    /// Counts fit a feature exactly when they have the shape of the statistics made for it,
    /// for every kind of image and for features that are not images.
    #[test]
    fn image_counts_fit_the_features_whose_statistics_they_shape_like() {
        use crate::episode::{Dtype, FeatureKind, FeatureSet, FeatureSpec, standard_features};
        let set = FeatureSet {
            depth: true,
            mask: true,
            environment_state: true,
        };
        let mut features = standard_features(8, 8, set);
        for (channels, dtype) in [(1, Dtype::Image), (3, Dtype::Image), (4, Dtype::Image)] {
            features.push(FeatureSpec {
                name: format!("theirs.{channels}"),
                dtype,
                shape: vec![8, 8, channels],
                names: Vec::new(),
                kind: FeatureKind::Other,
                video: None,
                info: Default::default(),
            });
        }
        let kinds: Vec<FeatureKind> = features.iter().map(|f| f.kind).collect();
        assert!(kinds.contains(&FeatureKind::Depth) && kinds.contains(&FeatureKind::Rgb));
        let mut images = 0;
        for a in &features {
            let FeatureStats::Image(counts) = FeatureStats::for_feature(a) else {
                continue;
            };
            images += 1;
            for b in &features {
                let expected = match FeatureStats::for_feature(b) {
                    FeatureStats::Image(other) => counts.same_shape(&other),
                    _ => false,
                };
                assert_eq!(counts.fits(b), expected, "{} against {}", a.name, b.name);
            }
            assert!(counts.fits(a), "{}", a.name);
        }
        assert!(images >= 5, "every kind of image was tried");
    }

    /// A checkpoint's reservoirs come back bit for bit (NaN, infinities, -0 and subnormals
    /// included), from the hex form and from the list of numbers written before; a damaged
    /// hex text is refused, and an altered reservoir never panics a merge.
    #[test]
    fn reservoirs_round_trip_through_a_checkpoint_bit_for_bit() {
        let mut rng = crate::rng::SplitMix64::new(11);
        let mut stats = VectorStats::new(3);
        let specials = [
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            -0.0,
            f32::MIN_POSITIVE / 4.0,
        ];
        for k in 0..12_000 {
            let v = f32::from_bits(rng.next_u64() as u32);
            let special = specials[k % specials.len()];
            stats.push(&[v, special, k as f32 * 0.25]);
        }
        let text = serde_json::to_string(&stats).expect("write");
        let back: VectorStats = serde_json::from_str(&text).expect("read");
        let bits = |s: &VectorStats| -> Vec<Vec<u32>> {
            (s.reservoirs.iter())
                .map(|r| r.iter().map(|v| v.to_bits()).collect())
                .collect()
        };
        assert_eq!(bits(&back), bits(&stats));
        assert_eq!(back.reservoirs[0].len(), RESERVOIR);
        assert_eq!(back.seen, stats.seen);
        // Running sums with NaN and infinities, and an empty series' infinite bounds.
        let running = |s: &VectorStats| -> Vec<[u64; 5]> {
            (s.running.iter())
                .map(|r| {
                    let b = |v: f64| if v.is_nan() { u64::MAX } else { v.to_bits() };
                    [r.count, b(r.sum), b(r.sum_sq), b(r.min), b(r.max)]
                })
                .collect()
        };
        assert_eq!(running(&back), running(&stats));
        assert!(back.running[1].sum.is_nan());
        let empty = VectorStats::new(2);
        let read: VectorStats =
            serde_json::from_str(&serde_json::to_string(&empty).expect("write")).expect("read");
        assert_eq!(running(&read), running(&empty));
        assert_eq!(read.running[0].min, f64::INFINITY);
        // The list of numbers written before.
        let mut old = serde_json::to_value(&stats).expect("value");
        old["reservoirs"] = serde_json::json!([[1.5, -2.0], [0.0, 3.25], [7.0, 8.0]]);
        let read: VectorStats = serde_json::from_value(old.clone()).expect("read");
        assert_eq!(read.reservoirs[1], vec![0.0, 3.25]);
        for bad in ["3fc0000", "3fc0000g", "+fc00000"] {
            old["reservoirs"] = serde_json::json!([bad, "", ""]);
            assert!(
                serde_json::from_value::<VectorStats>(old.clone()).is_err(),
                "{bad}"
            );
        }
        // Reservoirs of unequal length (an altered checkpoint) merge without a panic.
        old["reservoirs"] = serde_json::json!([[1.0], [], [2.0, 3.0]]);
        let altered: VectorStats = serde_json::from_value(old).expect("read");
        let mut total = VectorStats::new(3);
        total.merge(&altered);
        total.merge(&stats);
        let mut again = altered.clone();
        again.merge(&stats);
    }

    #[test]
    fn carried_statistics_are_written_back_as_read_until_changed() {
        let mut depth = ImageStats::depth();
        depth.push_depth(&[0.05, 0.1, 0.0, 0.2]);
        let mut stored = serde_json::to_value(&depth).expect("json");
        // An input's own spelling (a field order, a key of its own, spaces) is kept as it is.
        stored["theirs"] = json!(1);
        let stored = serde_json::to_string_pretty(&stored).expect("text");
        let carried = ImageStats::carried(&stored).expect("carried");
        assert_eq!(carried.stored_json(), stored);
        assert!(carried.same_shape(&depth));
        let json =
            |s: &ImageStats| -> Value { serde_json::from_str(&s.stored_json()).expect("json") };
        // Changed, they are written anew (compact).
        let mut merged = carried.clone();
        merged.merge(&depth);
        assert_ne!(merged.stored_json(), stored);
        assert_eq!(json(&merged)["frames"], json!(2));
        assert!(json(&merged).get("theirs").is_none());
        assert_eq!(merged.stored_json(), json(&merged).to_string());
        // Whichever way the counts change, the JSON read is forgotten.
        let changes: [&dyn Fn(&mut ImageStats); 4] = [
            &|s| s.push_depth(&[0.3]),
            &|s| {
                let mut histograms = s.empty_histograms();
                s.push_depth_counting(&[0.3], &mut histograms);
            },
            &|s| {
                let histograms = s.empty_histograms();
                s.add_histograms(&histograms);
            },
            &|s| s.merge(&ImageStats::depth()),
        ];
        for change in changes {
            let mut changed = carried.clone();
            change(&mut changed);
            assert!(json(&changed).get("theirs").is_none());
        }
        assert!(ImageStats::carried(r#"{"frames": "two"}"#).is_none());
        // Anything after the one value is not statistics.
        let trailing = format!("{stored} {{}}");
        assert!(ImageStats::carried(&trailing).is_none());
    }

    #[test]
    fn image_statistics_store_only_the_bins_that_count_and_read_back_alike() {
        let mut depth = ImageStats::depth();
        depth.push_depth(&[0.1, 0.1005, 0.12, 0.3]);
        let stored = serde_json::to_value(&depth).expect("json");
        let span = &stored["histograms"][0];
        assert_eq!(span["bins"], json!(DEPTH_BINS));
        // 0.1 m is bin 1638, 0.3 m bin 4915: the span between them, nothing around it.
        assert_eq!(span["from"], json!(1638));
        let counts = span["counts"].as_str().expect("counts");
        assert_eq!(counts.split(' ').count(), 4915 - 1638 + 1);
        assert!(counts.starts_with("1 0 0 "), "{counts:.20}");
        let back: ImageStats = serde_json::from_value(stored).expect("read back");
        assert!(back.same_shape(&depth));
        assert_eq!(back.to_json(), depth.to_json());
        assert_eq!(back.histograms, depth.histograms);
        // Empty statistics, and the full arrays surgvla stored before.
        let empty = ImageStats::unit_scaled(3);
        let text = serde_json::to_string(&empty).expect("json");
        assert!(
            text.contains(r#"{"bins":256,"from":0,"counts":""}"#),
            "{text}"
        );
        let mut value = serde_json::to_value(&depth).expect("json");
        value["histograms"] = json!([{"bins": 256, "from": 0, "counts": ""}]);
        let back: ImageStats = serde_json::from_value(value).expect("an empty span");
        assert_eq!(back.histograms, vec![vec![0; 256]]);
        let mut full = serde_json::to_value(&depth).expect("json");
        full["histograms"] = json!([depth.histograms[0].clone()]);
        let back: ImageStats = serde_json::from_value(full).expect("full arrays");
        assert_eq!(back.histograms, depth.histograms);
        assert!(!back.same_shape(&ImageStats::unit_scaled(1)));
        // A hostile accumulator: too many bins, a count not a number, counts past the end.
        for bad in [
            json!({"bins": 1u64 << 40, "from": 0, "counts": ""}),
            json!({"bins": 4, "from": 0, "counts": "1 -2"}),
            json!({"bins": 4, "from": 3, "counts": [1, 2]}),
        ] {
            let mut value = serde_json::to_value(&depth).expect("json");
            value["histograms"] = json!([bad]);
            assert!(serde_json::from_value::<ImageStats>(value).is_err());
        }
    }

    #[test]
    fn summaries_merge_by_count_and_meet_exact_statistics() {
        let mut a = ImageStats::unit_scaled(1);
        a.push_u8(&[0, 255, 0, 255]);
        let mut b = ImageStats::unit_scaled(1);
        b.push_u8(&[255, 255, 255, 255]);
        b.push_u8(&[255, 255, 255, 255]);
        let part = |s: &ImageStats| {
            FeatureStats::Summary(SummaryStats::from_json(&s.to_json()).expect("summary"))
        };
        let mut total = FeatureStats::Image(ImageStats::unit_scaled(1));
        total.merge(&part(&a));
        total.merge(&FeatureStats::Image(b.clone()));
        let json = total.to_json();
        assert_eq!(json["count"], json!([3]));
        assert_eq!(json["min"], json!([[[0.0]]]));
        assert_eq!(json["max"], json!([[[1.0]]]));
        // 10 of 12 pixels are 1: the pooled mean and deviation are exact.
        let mean = json["mean"][0][0][0].as_f64().expect("mean");
        assert!((mean - (0.5 + 2.0) / 3.0).abs() < 1e-12, "{mean}");
        let exact = {
            let mut e = a.clone();
            e.merge(&b);
            e.to_json()
        };
        let std = json["std"][0][0][0].as_f64().expect("std");
        let exact_std = exact["std"][0][0][0].as_f64().expect("std");
        assert!((std - exact_std).abs() < 1e-12, "{std} vs {exact_std}");
        // Quantiles are weighted means of the parts' (here the median: 1/3 * 0 + 2/3 * 1 at
        // most; a's median of [0, 1, 0, 1] is 0 or 1 by rank).
        assert!(json["q50"][0][0][0].as_f64().is_some());
        assert!(SummaryStats::from_json(&json!({"count": [1]})).is_none());
    }

    /// One part's summary is stated as it was read, to the last bit, however its numbers
    /// round when weighted by its count (a kept episode's row keeps what another tool wrote);
    /// two parts merged are pooled.
    #[test]
    fn one_summary_is_stated_as_read_and_two_are_pooled() {
        let mut rng = crate::rng::SplitMix64::new(48);
        let mut uniform = || (rng.next_u64() >> 11) as f64 / (1u64 << 53) as f64;
        for round in 0..200 {
            let values = |f: &mut dyn FnMut() -> f64| -> Vec<Value> {
                (0..3).map(|_| json!([[f()]])).collect()
            };
            let mut stats = serde_json::Map::new();
            for name in ["min", "max", "mean", "std"]
                .into_iter()
                .chain(QUANTILES.iter().map(|(n, _)| *n))
            {
                stats.insert(name.into(), Value::Array(values(&mut uniform)));
            }
            stats.insert("count".into(), json!([1 + round * 37]));
            let read = Value::Object(stats);
            let one = SummaryStats::from_json(&read).expect("a summary");
            assert_eq!(one.to_json(), read, "round {round}");
            let mut two = one.clone();
            two.merge(&one);
            let pooled = two.to_json();
            assert_eq!(pooled["count"], json!([2 * (1 + round * 37)]));
            let (mean, pooled_mean) = (flat(&read["mean"]), flat(&pooled["mean"]));
            for (m, p) in mean.iter().zip(&pooled_mean) {
                assert!((m - p).abs() <= 1e-15, "round {round}: {m} vs {p}");
            }
        }
    }

    #[test]
    fn vector_stats_match_direct_computation() {
        let mut stats = VectorStats::new(2);
        for i in 0..101 {
            stats.push(&[i as f32, -(i as f32) * 0.5]);
        }
        let json = stats.to_json();
        assert_eq!(json["min"], json!([0.0, -50.0]));
        assert_eq!(json["max"], json!([100.0, 0.0]));
        assert_eq!(json["mean"], json!([50.0, -25.0]));
        assert_eq!(json["q50"], json!([50.0, -25.0]));
        assert_eq!(json["q10"], json!([10.0, -45.0]));
        assert_eq!(json["count"], json!([101]));
        let std = json["std"][0].as_f64().unwrap_or_default();
        assert!((std - 29.154759).abs() < 1e-5, "{std}");
    }

    #[test]
    fn image_stats_are_per_channel_and_unit_scaled() {
        let mut stats = ImageStats::unit_scaled(3);
        let pixels: Vec<u8> = (0..100).flat_map(|_| [0u8, 255, 51]).collect();
        stats.push_u8(&pixels);
        let json = stats.to_json();
        assert_eq!(json["min"], json!([[[0.0]], [[1.0]], [[0.2]]]));
        assert_eq!(json["q99"], json!([[[0.0]], [[1.0]], [[0.2]]]));
        assert_eq!(json["count"], json!([1]));
    }

    /// The straightforward per-pixel count [`count_u8`] replaced: one counter per channel
    /// value.
    fn naive_u8(stats: &mut ImageStats, pixels: &[u8]) {
        stats.frames += 1;
        let channels = stats.running.len();
        let mut counts = vec![[0u64; 256]; channels];
        for chunk in pixels.chunks_exact(channels) {
            for (c, v) in chunk.iter().enumerate() {
                counts[c][usize::from(*v)] += 1;
            }
        }
        for (c, counts) in counts.iter().enumerate() {
            stats.running[c].merge(&fold_counts(counts));
            for (bin, n) in stats.histograms[c].iter_mut().zip(counts) {
                *bin += n;
            }
        }
    }

    #[test]
    fn u8_statistics_equal_the_per_pixel_count_bit_for_bit() {
        let mut rng = SplitMix64::new(27);
        for channels in [1usize, 3, 4] {
            let mut fast = ImageStats::unit_scaled(channels);
            let mut split = ImageStats::unit_scaled(channels);
            let mut split_counts = split.empty_histograms();
            let mut naive = ImageStats::unit_scaled(channels);
            for frame in 0..6 {
                // Flat runs (rendered colour) and noise, lengths that leave partial groups
                // of four pixels and a partial pixel.
                let len = 97 * channels + frame * 5 + 1;
                let pixels: Vec<u8> = (0..len)
                    .map(|i| {
                        if (i / 40) % 2 == 0 {
                            (i % channels * 60) as u8
                        } else {
                            rng.next_u64() as u8
                        }
                    })
                    .collect();
                fast.push_u8(&pixels);
                split.push_u8_counting(&pixels, &mut split_counts);
                naive_u8(&mut naive, &pixels);
            }
            split.add_histograms(&split_counts);
            let expected = serde_json::to_string(&naive).expect("json");
            assert_eq!(serde_json::to_string(&fast).expect("json"), expected);
            assert_eq!(serde_json::to_string(&split).expect("json"), expected);
        }
    }

    #[test]
    fn counting_since_the_last_frame_equals_counting_every_frame() {
        // Seeded: a series whose frames change in a few random stretches (a moving
        // instrument), sometimes everywhere or not at all, sometimes in size (a new count).
        let mut rng = SplitMix64::new(41);
        for channels in [1usize, 3, 4] {
            let mut whole = ImageStats::unit_scaled(channels);
            let mut whole_counts = whole.empty_histograms();
            let mut since = ImageStats::unit_scaled(channels);
            let mut since_counts = since.empty_histograms();
            let mut last = LastFrame::default();
            let mut pixels: Vec<u8> = (0..4_000 * channels)
                .map(|_| rng.next_u64() as u8)
                .collect();
            let mut resized = 0;
            for frame in 0..40 {
                match rng.next_u64() % 8 {
                    0 => {}
                    1 => pixels.iter_mut().for_each(|p| *p = rng.next_u64() as u8),
                    2 => pixels.resize(pixels.len() + 1 + (rng.next_u64() % 300) as usize, 9),
                    _ => {
                        for _ in 0..1 + rng.next_u64() % 4 {
                            let start = (rng.next_u64() % pixels.len() as u64) as usize;
                            let end = (start + (rng.next_u64() % 500) as usize).min(pixels.len());
                            let value = rng.next_u64() as u8;
                            pixels[start..end].iter_mut().for_each(|p| *p = value);
                        }
                    }
                }
                let before = last.pixels.len();
                whole.push_u8_counting(&pixels, &mut whole_counts);
                since.push_u8_counting_since(&pixels, &mut since_counts, &mut last);
                resized += usize::from(before != last.pixels.len());
                let frame_counts = count_u8(&pixels, channels);
                assert_eq!(
                    last.counts, frame_counts,
                    "{channels} channels, frame {frame}"
                );
            }
            same_series(whole, &whole_counts, since, &since_counts, resized);
        }
    }

    /// A series counted frame by frame and since the last frame ended the same, with fewer
    /// than half of its 40 frames counted whole for a new size.
    fn same_series(
        mut whole: ImageStats,
        whole_counts: &[Vec<u64>],
        mut since: ImageStats,
        since_counts: &[Vec<u64>],
        resized: usize,
    ) {
        assert!(resized < 20, "most frames count only what changed");
        whole.add_histograms(whole_counts);
        since.add_histograms(since_counts);
        assert_eq!(
            serde_json::to_string(&since).expect("json"),
            serde_json::to_string(&whole).expect("json")
        );
    }

    #[test]
    fn depth_parts_with_shared_histograms_equal_whole_frames() {
        let mut rng = SplitMix64::new(7);
        let frames: Vec<Vec<f32>> = (0..5)
            .map(|_| {
                (0..300)
                    .map(|_| (rng.next_u64() % 6000) as f32 * 1e-4 - 0.05)
                    .collect()
            })
            .collect();
        let mut whole = ImageStats::depth();
        for frame in &frames {
            whole.push_depth(frame);
        }
        let mut parts = ImageStats::depth();
        let mut counts = parts.empty_histograms();
        for frame in &frames {
            let mut part = parts.without_histograms();
            part.push_depth_counting(frame, &mut counts);
            parts.merge(&part);
        }
        parts.add_histograms(&counts);
        assert_eq!(
            serde_json::to_string(&parts).expect("json"),
            serde_json::to_string(&whole).expect("json")
        );
    }

    #[test]
    fn depth_counted_since_the_last_frame_equals_every_frame_counted() {
        // Seeded: depth series changing in random stretches, now and then everywhere, in
        // size, or to values out of range, NaN, -0 and 0 (bits, not values, decide).
        let mut rng = SplitMix64::new(43);
        let value = |rng: &mut SplitMix64| match rng.next_u64() % 16 {
            0 => f32::NAN,
            1 => -0.0,
            2 => 0.0,
            3 => 0.9,
            _ => (rng.next_u64() % 6000) as f32 * 1e-4 - 0.05,
        };
        let mut frame: Vec<f32> = (0..3_001).map(|_| value(&mut rng)).collect();
        let mut whole = ImageStats::depth();
        let mut whole_counts = whole.empty_histograms();
        let mut since = ImageStats::depth();
        let mut since_counts = since.empty_histograms();
        let mut last = LastFrame::default();
        let mut resized = 0;
        for step in 0..40 {
            match rng.next_u64() % 8 {
                0 => {}
                1 => frame.iter_mut().for_each(|v| *v = value(&mut rng)),
                2 => frame.truncate(frame.len() - 1 - (rng.next_u64() % 200) as usize),
                _ => {
                    for _ in 0..1 + rng.next_u64() % 4 {
                        let start = (rng.next_u64() % frame.len() as u64) as usize;
                        let end = (start + (rng.next_u64() % 400) as usize).min(frame.len());
                        let v = value(&mut rng);
                        frame[start..end].iter_mut().for_each(|x| *x = v);
                    }
                }
            }
            let before = last.depth.len();
            let mut part = whole.without_histograms();
            part.push_depth_counting(&frame, &mut whole_counts);
            whole.merge(&part);
            let mut part = since.without_histograms();
            part.push_depth_counting_since(&frame, &mut since_counts, &mut last);
            since.merge(&part);
            resized += usize::from(before != last.depth.len());
            assert_eq!(whole_counts, since_counts, "step {step}");
        }
        same_series(whole, &whole_counts, since, &since_counts, resized);
    }

    #[test]
    fn depth_bins_in_f32_equal_the_f64_formula_ties_included() {
        let per_bin = 1.0 / ImageStats::depth().bin_width;
        let bins = DepthBins::new(per_bin, DEPTH_BINS);
        let last = DEPTH_BINS - 1;
        let reference = |x: f32| ((f64::from(x) * per_bin + 0.5) as usize).min(last);
        let mut rng = SplitMix64::new(11);
        let mut values: Vec<f32> = (0..200_000)
            .map(|_| f32::from_bits(rng.next_u64() as u32 % 0x3f80_0000))
            .collect();
        // Ties: halfway between two bins, and the values beside them.
        for b in 0..DEPTH_BINS as u32 {
            let tie = (b as f32 + 0.5) / per_bin as f32;
            values.extend([tie, tie.next_down(), tie.next_up()]);
        }
        values.extend([
            0.0,
            -0.0,
            -1.0,
            0.49999,
            0.5,
            1e9,
            f32::NAN,
            f32::INFINITY,
            f32::NEG_INFINITY,
            f32::MIN_POSITIVE / 4.0,
        ]);
        for x in values {
            assert_eq!(
                bins.bin(x) as usize,
                reference(x),
                "{x:e} ({:#x})",
                x.to_bits()
            );
        }
    }

    #[test]
    fn depth_lanes_meet_the_sequential_sums() {
        let mut rng = SplitMix64::new(5);
        for len in [0, 1, 3, 4, 5, 1001] {
            let frame: Vec<f32> = (0..len)
                .map(|_| (rng.next_u64() % 4000) as f32 * 1e-4 + 0.01)
                .collect();
            let mut stats = ImageStats::depth();
            stats.push_depth(&frame);
            let mut sequential = Running::default();
            for v in &frame {
                sequential.push(f64::from(*v));
            }
            let lanes = &stats.running[0];
            assert_eq!(lanes.count, sequential.count);
            // These depths are multiples of 2^-33 far from overflow: their sum is exact in any
            // order.
            assert_eq!(lanes.sum, sequential.sum);
            assert!((lanes.sum_sq - sequential.sum_sq).abs() <= 1e-12 * sequential.sum_sq);
            assert_eq!(lanes.finite_min(), sequential.finite_min());
            assert_eq!(lanes.finite_max(), sequential.finite_max());
            assert_eq!(stats.histograms[0].iter().sum::<u64>(), len as u64);
        }
    }

    #[test]
    fn depth_quantiles_land_on_the_histogram_grid() {
        let mut stats = ImageStats::depth();
        let depth: Vec<f32> = (0..1000).map(|i| 0.1 + i as f32 * 1e-4).collect();
        stats.push_depth(&depth);
        let q50 = stats.to_json()["q50"][0][0][0].as_f64().unwrap_or_default();
        assert!(
            (q50 - 0.15).abs() < 2.0 * DEPTH_RANGE_M / DEPTH_BINS as f64,
            "{q50}"
        );
    }
}

/// Statistics known only as LeRobot's per-episode summaries (a video feature of a dataset
/// surgvla did not write, whose pixels nothing here decodes): merged the way lerobot merges
/// them, by count: min and max exact, mean and standard deviation pooled exactly, quantiles
/// the count-weighted mean of the parts' quantiles (an approximation).
#[derive(Clone, Debug, Default, serde::Serialize, serde::Deserialize)]
pub struct SummaryStats {
    count: u64,
    /// Per element (or channel).
    min: Vec<f64>,
    max: Vec<f64>,
    /// Count-weighted sums of mean, mean of squares and each quantile.
    weighted_mean: Vec<f64>,
    weighted_square: Vec<f64>,
    weighted_quantiles: Vec<Vec<f64>>,
    /// Whether each statistic nests as (C, 1, 1) (images) rather than a flat list.
    image: bool,
    /// The one part read, as read (none once parts are merged): stated as it was, where
    /// weighting by the count and dividing by it again could move a number by a rounding.
    #[serde(default)]
    one_part: Option<OnePart>,
}

/// A [`SummaryStats`] part's mean, standard deviation and quantiles (per element), as read.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
struct OnePart {
    mean: Vec<f64>,
    std: Vec<f64>,
    quantiles: Vec<Vec<f64>>,
}

/// Every number of a (nested) JSON list, in order.
pub(crate) fn flat(value: &Value) -> Vec<f64> {
    match value {
        Value::Array(items) => items.iter().flat_map(flat).collect(),
        other => other.as_f64().into_iter().collect(),
    }
}

impl SummaryStats {
    /// One part from LeRobot's per-episode statistics object (min, max, mean, std, count,
    /// q01..q99); None when it lacks one of them.
    pub fn from_json(stats: &Value) -> Option<Self> {
        let count = flat(&stats["count"]).first().copied()? as u64;
        let (min, max, mean, std) = (
            flat(&stats["min"]),
            flat(&stats["max"]),
            flat(&stats["mean"]),
            flat(&stats["std"]),
        );
        let n = mean.len();
        if n == 0 || [min.len(), max.len(), std.len()] != [n, n, n] {
            return None;
        }
        let quantiles: Vec<Vec<f64>> = QUANTILES
            .iter()
            .map(|(name, _)| flat(&stats[*name]))
            .collect();
        if quantiles.iter().any(|q| q.len() != n) {
            return None;
        }
        let weight = count as f64;
        Some(SummaryStats {
            count,
            min,
            max,
            weighted_square: mean
                .iter()
                .zip(&std)
                .map(|(m, s)| (s * s + m * m) * weight)
                .collect(),
            weighted_mean: mean.iter().map(|m| m * weight).collect(),
            weighted_quantiles: (quantiles.iter())
                .map(|q| q.iter().map(|v| v * weight).collect())
                .collect(),
            image: matches!(&stats["mean"], Value::Array(a) if a.first().is_some_and(Value::is_array)),
            one_part: Some(OnePart {
                mean,
                std,
                quantiles,
            }),
        })
    }

    /// Folds in another part.
    pub fn merge(&mut self, other: &SummaryStats) {
        if other.count == 0 {
            return;
        }
        if self.count == 0 {
            *self = other.clone();
            return;
        }
        self.count += other.count;
        self.one_part = None;
        let add = |a: &mut Vec<f64>, b: &Vec<f64>| a.iter_mut().zip(b).for_each(|(x, y)| *x += y);
        self.min
            .iter_mut()
            .zip(&other.min)
            .for_each(|(a, b)| *a = a.min(*b));
        self.max
            .iter_mut()
            .zip(&other.max)
            .for_each(|(a, b)| *a = a.max(*b));
        add(&mut self.weighted_mean, &other.weighted_mean);
        add(&mut self.weighted_square, &other.weighted_square);
        for (a, b) in self
            .weighted_quantiles
            .iter_mut()
            .zip(&other.weighted_quantiles)
        {
            add(a, b);
        }
    }

    /// The statistics as LeRobot states them (images nested (C, 1, 1)).
    pub fn stated(&self) -> Stated {
        let weight = (self.count as f64).max(1.0);
        let OnePart {
            mean,
            std,
            quantiles,
        } = self.one_part.clone().unwrap_or_else(|| {
            let mean: Vec<f64> = self.weighted_mean.iter().map(|v| v / weight).collect();
            let std = (self.weighted_square.iter().zip(&mean))
                .map(|(sq, m)| (sq / weight - m * m).max(0.0).sqrt())
                .collect();
            let quantiles = (self.weighted_quantiles.iter())
                .map(|q| q.iter().map(|v| v / weight).collect())
                .collect();
            OnePart {
                mean,
                std,
                quantiles,
            }
        });
        Stated {
            image: self.image,
            moments: [self.min.clone(), self.max.clone(), mean, std],
            count: self.count,
            quantiles: QUANTILES
                .iter()
                .map(|(name, _)| *name)
                .zip(quantiles)
                .collect(),
        }
    }

    /// The statistics as LeRobot's JSON (images nested (C, 1, 1)).
    pub fn to_json(&self) -> Value {
        self.stated().to_json()
    }
}

/// Statistics of one feature (or one of LeRobot's default columns): per element for vectors,
/// per channel for images.
#[derive(Clone, Debug, serde::Serialize, serde::Deserialize)]
pub enum FeatureStats {
    Vector(VectorStats),
    Image(ImageStats),
    /// Only per-episode summaries are known (see [`SummaryStats`]).
    Summary(SummaryStats),
}

impl FeatureStats {
    /// Empty statistics of the right shape for `feature`.
    pub fn for_feature(feature: &crate::episode::FeatureSpec) -> Self {
        use crate::episode::{Dtype, FeatureKind};
        match (image_shape(feature), feature.kind) {
            (Some((channels, bins, bin_width)), _) => {
                FeatureStats::Image(ImageStats::empty(channels, bins, bin_width))
            }
            // Text has no statistics: no elements to gather (and none written).
            (None, FeatureKind::Other) if feature.dtype == Dtype::String => {
                FeatureStats::Vector(VectorStats::new(0))
            }
            _ => FeatureStats::Vector(VectorStats::new(feature.shape.iter().product())),
        }
    }

    /// Statistics of a scalar column.
    pub fn scalar() -> Self {
        FeatureStats::Vector(VectorStats::new(1))
    }

    /// Folds `part` (statistics of later values) into these.
    pub fn merge(&mut self, part: &FeatureStats) {
        match (&mut *self, part) {
            (FeatureStats::Vector(a), FeatureStats::Vector(b)) => a.merge(b),
            (FeatureStats::Image(a), FeatureStats::Image(b)) => a.merge(b),
            (FeatureStats::Summary(a), FeatureStats::Summary(b)) => a.merge(b),
            // Exact statistics meeting summaries become a summary.
            (FeatureStats::Summary(a), exact) => {
                if let Some(b) = SummaryStats::from_json(&exact.to_json()) {
                    a.merge(&b);
                }
            }
            (exact, FeatureStats::Summary(b)) => {
                let mut merged = SummaryStats::from_json(&exact.to_json()).unwrap_or_default();
                merged.merge(b);
                *self = FeatureStats::Summary(merged);
            }
            _ => {}
        }
    }

    /// The statistics as LeRobot states them.
    pub fn stated(&self) -> Stated {
        match self {
            FeatureStats::Vector(s) => s.stated(),
            FeatureStats::Image(s) => s.stated(),
            FeatureStats::Summary(s) => s.stated(),
        }
    }

    /// The statistics as LeRobot's JSON.
    pub fn to_json(&self) -> Value {
        self.stated().to_json()
    }
}

//! The charts surgvla draws: [`rate_chart`] (success rates in [0, 1] with their intervals, one
//! bar per series and category, categories grouped) and [`dataset_chart`] (a histogram of
//! episode lengths per task, and each state and action dimension's range).

use super::{BLACK, Canvas, DARK, GLYPH_PX, GREY, SERIES, WHITE, fit};

/// A rate with its interval, all in [0, 1].
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Rate {
    pub value: f64,
    pub low: f64,
    pub high: f64,
}

/// One category on the x axis (a task) and the group it belongs to (its level).
#[derive(Clone, Debug, PartialEq)]
pub struct Category {
    pub label: String,
    pub group: String,
}

/// Rates of several series (policies) over categories (tasks): `rates[series][category]`,
/// None where a series has no value.
#[derive(Clone, Debug, PartialEq)]
pub struct RateChart {
    pub title: String,
    pub series: Vec<String>,
    pub categories: Vec<Category>,
    pub rates: Vec<Vec<Option<Rate>>>,
}

/// The plot area's height in pixels: a rate of 1 is a bar this tall.
pub const PLOT_HEIGHT_PX: usize = 240;
/// Room above the plot: the title, the legend, and the value labels of bars at 100 %.
const TOP_PX: usize = 76;
const LEFT_PX: usize = 56;
const BAR_PX: usize = 14;
/// The height a bar of 0 % is drawn (so that it shows, as a stub on the axis).
pub const MIN_BAR_PX: usize = 2;
const CATEGORY_GAP_PX: usize = 18;
/// Characters of a category's label under its bars.
const LABEL_CHARS: usize = 6;

/// The bars' geometry: where category `c`'s bar of series `s` starts (x), and the bottom of the
/// plot (y of a rate of 0).
#[derive(Clone, Copy, Debug)]
pub struct BarLayout {
    slot_px: usize,
    series: usize,
}

impl BarLayout {
    fn new(series: usize) -> Self {
        let bars = series.max(1) * BAR_PX;
        BarLayout {
            slot_px: bars.max(LABEL_CHARS * GLYPH_PX) + CATEGORY_GAP_PX,
            series: series.max(1),
        }
    }

    /// The left edge of the bar of `series` in `category`.
    pub fn bar_x(&self, category: usize, series: usize) -> usize {
        let bars = self.series * BAR_PX;
        LEFT_PX + category * self.slot_px + (self.slot_px - bars) / 2 + series * BAR_PX
    }

    /// The y of rate 0 (the plot's bottom).
    pub fn zero_y() -> usize {
        TOP_PX + PLOT_HEIGHT_PX
    }

    /// The y of `rate` (clamped to [0, 1]).
    pub fn y_of(rate: f64) -> usize {
        let height = (rate.clamp(0.0, 1.0) * PLOT_HEIGHT_PX as f64).round() as usize;
        Self::zero_y() - height
    }

    /// A bar's width in pixels.
    pub fn bar_px() -> usize {
        BAR_PX
    }
}

/// Under the bars: each category's label, then each group's label under its categories,
/// groups split by a line.
fn category_labels(canvas: &mut Canvas, chart: &RateChart, layout: &BarLayout) {
    let label_y = BarLayout::zero_y() + 6;
    let mut start = 0;
    for (c, category) in chart.categories.iter().enumerate() {
        let centre = LEFT_PX + c * layout.slot_px + layout.slot_px / 2;
        canvas.text_centred(
            centre,
            label_y,
            &fit(&category.label, LABEL_CHARS),
            1,
            BLACK,
        );
        let last = chart
            .categories
            .get(c + 1)
            .is_none_or(|n| n.group != category.group);
        if last {
            let (x0, x1) = (
                LEFT_PX + start * layout.slot_px,
                LEFT_PX + (c + 1) * layout.slot_px,
            );
            let chars = (x1 - x0) / GLYPH_PX;
            canvas.text_centred(
                (x0 + x1) / 2,
                label_y + 16,
                &fit(&category.group, chars),
                1,
                DARK,
            );
            if c + 1 < chart.categories.len() {
                canvas.vline(x1, TOP_PX, label_y + 26, GREY);
            }
            start = c + 1;
        }
    }
}

/// Draws `chart`; returns the canvas and the layout its bars follow (tests read pixels there).
pub fn rate_chart(chart: &RateChart) -> (Canvas, BarLayout) {
    let layout = BarLayout::new(chart.series.len());
    let categories = chart.categories.len().max(1);
    let legend_px = chart
        .series
        .iter()
        .map(|s| Canvas::text_width(&fit(s, 28), 1) + 24)
        .max()
        .unwrap_or(0);
    let width = (LEFT_PX + categories * layout.slot_px + 16).max(LEFT_PX + legend_px + 16);
    let height = BarLayout::zero_y() + 56;
    let mut canvas = Canvas::new(width, height, WHITE);
    canvas.text(8, 8, &fit(&chart.title, (width - 16) / GLYPH_PX), 1, BLACK);
    // Legend: a swatch and a name per series, under the title.
    for (s, name) in chart.series.iter().enumerate() {
        let y = 22 + (s % 2) * 12;
        let x = 8 + (s / 2) * (legend_px + 8);
        canvas.fill(x, y, x + 8, y + 8, SERIES[s % SERIES.len()]);
        canvas.text(x + 12, y, &fit(name, 28), 1, BLACK);
    }
    // Grid lines and labels every 25 %.
    let right = LEFT_PX + categories * layout.slot_px;
    for quarter in 0..=4 {
        let rate = quarter as f64 / 4.0;
        let y = BarLayout::y_of(rate);
        canvas.hline(LEFT_PX, right, y, if quarter == 0 { BLACK } else { GREY });
        let label = format!("{}%", quarter * 25);
        canvas.text(
            LEFT_PX - 4 - Canvas::text_width(&label, 1),
            y.saturating_sub(4),
            &label,
            1,
            BLACK,
        );
    }
    canvas.vline(LEFT_PX, TOP_PX, BarLayout::zero_y(), BLACK);
    for (s, rates) in chart.rates.iter().enumerate() {
        let colour = SERIES[s % SERIES.len()];
        for (c, rate) in rates.iter().enumerate() {
            let Some(rate) = rate else {
                continue;
            };
            let x = layout.bar_x(c, s);
            // A rate of 0 % (or one too small to see) still shows: a stub of MIN_BAR_PX.
            let zero = BarLayout::zero_y();
            let top_y = BarLayout::y_of(rate.value).min(zero - MIN_BAR_PX);
            canvas.fill(x + 1, top_y, x + BAR_PX - 1, zero, colour);
            // The interval: a black whisker 3 px wide in a white halo, with caps, over the
            // bar's middle: it stands out on the bar and on the background alike.
            let middle = x + BAR_PX / 2;
            let (top, bottom) = (BarLayout::y_of(rate.high), BarLayout::y_of(rate.low));
            canvas.fill(
                middle - 2,
                top.saturating_sub(1),
                middle + 3,
                bottom + 2,
                WHITE,
            );
            canvas.fill(middle - 1, top, middle + 2, bottom + 1, BLACK);
            canvas.fill(middle - 3, top, middle + 4, top + 1, BLACK);
            canvas.fill(middle - 3, bottom, middle + 4, bottom + 1, BLACK);
        }
    }
    // Over everything, each bar's value in %, above its whisker: neighbouring series take
    // turns at two heights, so that their labels (wider than a bar) never meet.
    for (s, rates) in chart.rates.iter().enumerate() {
        for (c, rate) in rates.iter().enumerate() {
            let Some(rate) = rate else {
                continue;
            };
            let (middle, y) = value_label_at(&layout, c, s, rate.high);
            let label = format!("{:.0}", 100.0 * rate.value);
            let half = Canvas::text_width(&label, 1) / 2;
            canvas.fill(
                middle - half - 1,
                y - 1,
                middle + half + 1,
                y + GLYPH_PX + 1,
                WHITE,
            );
            canvas.text_centred(middle, y, &label, 1, BLACK);
        }
    }
    category_labels(&mut canvas, chart, &layout);
    (canvas, layout)
}

/// Where the value label of the bar of `series` in `category` is drawn: its centre x and top
/// y, above the whisker's top at `high` (the odd series one line higher).
pub fn value_label_at(
    layout: &BarLayout,
    category: usize,
    series: usize,
    high: f64,
) -> (usize, usize) {
    let middle = layout.bar_x(category, series) + BAR_PX / 2;
    let y = BarLayout::y_of(high) - 3 - GLYPH_PX - (series % 2) * (GLYPH_PX + 2);
    (middle, y)
}

/// A histogram: `counts` of equal bins spanning [`low`, `high`].
#[derive(Clone, Debug, PartialEq)]
pub struct Histogram {
    pub label: String,
    pub counts: Vec<u64>,
    pub low: f64,
    pub high: f64,
}

/// One dimension's observed range.
#[derive(Clone, Debug, PartialEq)]
pub struct Range {
    pub label: String,
    pub min: f64,
    pub max: f64,
}

const PANEL_W_PX: usize = 200;
const PANEL_H_PX: usize = 96;
/// Characters of a range row's label (surgvla's longest names, `tip_pitch_rad`, fit).
const LABEL_COLUMN_CHARS: usize = 14;
/// A histogram panel's rows besides its plot: its title, its peak's label, its x axis' labels.
const PANEL_EXTRA_PX: usize = 50;

/// One histogram panel with its top left at (x0, y0): its title, its bins scaled to the
/// tallest, the x axis' range in frames and the tallest bin's count.
fn histogram_panel(canvas: &mut Canvas, histogram: &Histogram, (x0, y0): (usize, usize)) {
    let peak = histogram.counts.iter().copied().max().unwrap_or(0).max(1);
    canvas.text(
        x0,
        y0,
        &fit(&histogram.label, PANEL_W_PX / GLYPH_PX),
        1,
        BLACK,
    );
    let bottom = y0 + 22 + PANEL_H_PX;
    canvas.hline(x0, x0 + PANEL_W_PX, bottom, BLACK);
    // A grey line at the tallest bin's height, under the bars.
    canvas.hline(x0, x0 + PANEL_W_PX, bottom - PANEL_H_PX, GREY);
    let bins = histogram.counts.len().max(1);
    let bin_px = PANEL_W_PX / bins;
    for (b, &count) in histogram.counts.iter().enumerate() {
        let height = (count as f64 / peak as f64 * PANEL_H_PX as f64).round() as usize;
        let x = x0 + b * bin_px;
        canvas.fill(x + 1, bottom - height, x + bin_px, bottom, SERIES[0]);
    }
    let low = format!("{:.0}", histogram.low);
    let high = format!("{:.0}", histogram.high);
    canvas.text(x0, bottom + 4, &low, 1, DARK);
    canvas.text(
        x0 + PANEL_W_PX - Canvas::text_width(&high, 1),
        bottom + 4,
        &high,
        1,
        DARK,
    );
    // The x axis is in frames; the tallest bin's count marks the y axis at its height.
    canvas.text_centred(x0 + PANEL_W_PX / 2, bottom + 4, "frames", 1, DARK);
    // Right-aligned just above the grey line at the tallest bin's height.
    let top = bottom - PANEL_H_PX;
    let most = format!("{peak} episodes");
    let width = Canvas::text_width(&most, 1);
    canvas.text(x0 + PANEL_W_PX - width, top - GLYPH_PX - 2, &most, 1, DARK);
}

/// `info --plot`: a histogram panel per entry of `histograms` (four to a row), then each
/// range as a row: its label, its min and max, and a bar placed on the scale shared by its
/// group (state, action).
pub fn dataset_chart(
    title: &str,
    histograms: &[Histogram],
    ranges: &[(String, Vec<Range>)],
) -> Canvas {
    let per_row = 4;
    let panel_rows = histograms.len().div_ceil(per_row);
    let range_rows: usize = ranges.iter().map(|(_, r)| r.len() + 2).sum();
    let width = 16 + per_row * (PANEL_W_PX + 16);
    let height = 32 + panel_rows * (PANEL_H_PX + PANEL_EXTRA_PX) + range_rows * 12 + 16;
    let mut canvas = Canvas::new(width, height, WHITE);
    canvas.text(8, 8, &fit(title, (width - 16) / GLYPH_PX), 1, BLACK);
    for (k, histogram) in histograms.iter().enumerate() {
        let x0 = 16 + (k % per_row) * (PANEL_W_PX + 16);
        let y0 = 32 + (k / per_row) * (PANEL_H_PX + PANEL_EXTRA_PX);
        histogram_panel(&mut canvas, histogram, (x0, y0));
    }
    let mut y = 32 + panel_rows * (PANEL_H_PX + PANEL_EXTRA_PX) + 8;
    let bar_x0 = 16 + LABEL_COLUMN_CHARS * GLYPH_PX + 2 * 10 * GLYPH_PX;
    let bar_x1 = width - 16;
    for (group, rows) in ranges {
        if rows.is_empty() {
            canvas.text(16, y, &format!("{group}: no values to draw"), 1, BLACK);
            y += 24;
            continue;
        }
        let low = rows.iter().map(|r| r.min).fold(f64::INFINITY, f64::min);
        let high = rows.iter().map(|r| r.max).fold(f64::NEG_INFINITY, f64::max);
        canvas.text(
            16,
            y,
            &format!("{group}: range of each dimension, on [{low:.3}, {high:.3}]"),
            1,
            BLACK,
        );
        y += 16;
        let span = (high - low).max(f64::MIN_POSITIVE);
        let to_x =
            |v: f64| bar_x0 + (((v - low) / span) * (bar_x1 - bar_x0) as f64).round() as usize;
        for row in rows {
            let label_px = LABEL_COLUMN_CHARS * GLYPH_PX;
            canvas.text(16, y, &fit(&row.label, LABEL_COLUMN_CHARS), 1, BLACK);
            canvas.text(16 + label_px, y, &format!("{:>9.3}", row.min), 1, DARK);
            let max_x = 16 + label_px + 10 * GLYPH_PX;
            canvas.text(max_x, y, &format!("{:>9.3}", row.max), 1, DARK);
            canvas.hline(bar_x0, bar_x1, y + 4, GREY);
            if low.is_finite() && high.is_finite() {
                canvas.fill(to_x(row.min), y + 1, to_x(row.max) + 1, y + 8, SERIES[1]);
            }
            y += 12;
        }
        y += 8;
    }
    canvas
}

#[cfg(test)]
mod tests {
    use super::*;

    fn chart() -> RateChart {
        let category = |label: &str, group: &str| Category {
            label: label.into(),
            group: group.into(),
        };
        let rate = |value: f64| {
            Some(Rate {
                value,
                low: (value - 0.1).max(0.0),
                high: (value + 0.1).min(1.0),
            })
        };
        RateChart {
            title: "success rate".into(),
            series: vec!["expert".into(), "random".into()],
            categories: vec![
                category("T1-1", "level 1"),
                category("T1-2", "level 1"),
                category("T3-1", "level 3"),
            ],
            rates: vec![
                vec![rate(1.0), rate(0.5), rate(0.25)],
                vec![rate(0.0), None, rate(0.75)],
            ],
        }
    }

    /// The height of the bar of `series` in `category`, read from the pixels.
    fn bar_height(canvas: &Canvas, layout: &BarLayout, category: usize, series: usize) -> usize {
        // A quarter into the bar: clear of the whisker in its middle.
        let x = layout.bar_x(category, series) + BarLayout::bar_px() / 4;
        let colour = SERIES[series];
        (0..BarLayout::zero_y())
            .rev()
            .take_while(|&y| canvas.at(x, y) == Some(colour))
            .count()
    }

    #[test]
    fn bars_are_as_tall_as_their_rates_in_their_series_colours() {
        let (canvas, layout) = rate_chart(&chart());
        // Three tasks of two bars: each slot as wide as a 6-character label plus the gap.
        assert_eq!((canvas.width_px, canvas.height_px), (270, 372));
        assert_eq!(canvas.pixels.len(), 270 * 372 * 3);
        let full = PLOT_HEIGHT_PX;
        assert_eq!(bar_height(&canvas, &layout, 0, 0), full);
        assert_eq!(bar_height(&canvas, &layout, 1, 0), full / 2);
        assert_eq!(bar_height(&canvas, &layout, 2, 0), full / 4);
        assert_eq!(bar_height(&canvas, &layout, 0, 1), MIN_BAR_PX, "0 % shows");
        assert_eq!(bar_height(&canvas, &layout, 1, 1), 0, "no value, no bar");
        assert_eq!(bar_height(&canvas, &layout, 2, 1), full * 3 / 4);
        // The whisker of the second bar reaches 0.6, above the bar's top at 0.5: black, 3 px
        // wide, in a white halo, inside the bar and above it.
        let middle = layout.bar_x(1, 0) + BarLayout::bar_px() / 2;
        for y in [BarLayout::y_of(0.57), BarLayout::y_of(0.45)] {
            let row: Vec<_> = (middle - 2..=middle + 2).map(|x| canvas.at(x, y)).collect();
            assert_eq!(row, [WHITE, BLACK, BLACK, BLACK, WHITE].map(Some), "at {y}");
        }
    }

    #[test]
    fn every_bar_carries_its_value_in_black_on_white() {
        let chart = chart();
        let (canvas, layout) = rate_chart(&chart);
        for (s, rates) in chart.rates.iter().enumerate() {
            for (c, rate) in rates.iter().enumerate() {
                let Some(rate) = rate else { continue };
                let (middle, y) = value_label_at(&layout, c, s, rate.high);
                let label = format!("{:.0}", 100.0 * rate.value);
                let half = Canvas::text_width(&label, 1) / 2;
                let (mut black, mut white) = (0, 0);
                for py in y..y + GLYPH_PX {
                    for px in middle - half..middle + half {
                        match canvas.at(px, py) {
                            Some(BLACK) => black += 1,
                            Some(WHITE) => white += 1,
                            other => panic!("{other:?} in the label of {c}, {s}"),
                        }
                    }
                }
                // The font draws a digit with 10 to 40 of its 64 pixels, the rest white.
                let digits = label.len();
                assert!(
                    (10 * digits..=40 * digits).contains(&black) && black + white == 64 * digits,
                    "{label}: {black} / {white}"
                );
                // Clear of the legend, which ends 42 px down.
                assert!(y > 42, "{label} at {y}");
            }
        }
        // The labels of the two series in one category stand at different heights.
        let (_, y0) = value_label_at(&layout, 2, 0, 0.35);
        let (_, y1) = value_label_at(&layout, 2, 1, 0.35);
        assert!(y0.abs_diff(y1) > GLYPH_PX, "{y0} {y1}");
    }

    #[test]
    fn the_same_rates_give_the_same_png_bytes() {
        let a = rate_chart(&chart()).0.png().expect("png");
        if let Ok(path) = std::env::var("SURGVLA_CHART_SNAPSHOT") {
            std::fs::write(path, &a).expect("snapshot");
        }
        let b = rate_chart(&chart()).0.png().expect("png");
        assert_eq!(a, b);
        assert_eq!(&a[1..4], b"PNG");
        // A snapshot of the bytes: the drawing, the font and the encoder all stay put.
        assert_eq!(
            format!("{:08x}", crc32c::crc32c(&a)),
            SNAPSHOT_CRC,
            "{} bytes",
            a.len()
        );
    }

    const SNAPSHOT_CRC: &str = "f37483e7";

    #[test]
    fn histograms_scale_to_their_peak() {
        let histogram = Histogram {
            label: "T1-1 episode length".into(),
            counts: vec![1, 4, 2, 0],
            low: 30.0,
            high: 70.0,
        };
        let ranges = vec![(
            "state".to_string(),
            vec![
                Range {
                    label: "state[0]".into(),
                    min: -1.0,
                    max: 0.0,
                },
                Range {
                    label: "state[1]".into(),
                    min: 0.0,
                    max: 1.0,
                },
            ],
        )];
        let canvas = dataset_chart("dataset", &[histogram], &ranges);
        let bottom = 32 + 22 + PANEL_H_PX;
        let x = |bin: usize| 16 + bin * (PANEL_W_PX / 4) + 5;
        let height = |bin: usize| {
            (0..bottom)
                .rev()
                .take_while(|&y| canvas.at(x(bin), y) == Some(SERIES[0]))
                .count()
        };
        assert_eq!(height(1), PANEL_H_PX, "the peak fills the panel");
        assert_eq!(height(0), PANEL_H_PX / 4);
        assert_eq!(height(3), 0);
        // The peak's count is written above the plot, at its right end, not among the x axis'
        // labels; "frames" names the x axis under it.
        let dark_in = |x0: usize, x1: usize, y0: usize, y1: usize| {
            (y0..y1).any(|y| (x0..x1).any(|x| canvas.at(x, y) == Some(DARK)))
        };
        let top = bottom - PANEL_H_PX;
        assert!(dark_in(16 + PANEL_W_PX / 2, 16 + PANEL_W_PX, top - 10, top));
        let under = bottom + 4..bottom + 4 + GLYPH_PX;
        let centre = 16 + PANEL_W_PX / 2;
        assert!(dark_in(centre - 24, centre + 24, under.start, under.end));
    }
}

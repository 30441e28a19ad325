//! The perturbation heatmap (`surgvla report` of a suite's run): one row per variant, one column
//! per task and a mean column; each cell coloured by its success rate on a colour-blind-safe
//! sequential scale and labelled with the rate, its Wilson 95 % interval and the change from
//! the unperturbed row, so a suite reads at a glance.

use super::plots::Rate;
use super::{BLACK, Canvas, DARK, GLYPH_PX, GREY, Rgb, WHITE, fit};

/// One cell: the rate and the change from the unperturbed run (None on that row).
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct HeatCell {
    pub rate: Rate,
    /// Unperturbed rate minus this one, -1..1.
    pub drop: Option<f64>,
}

/// One row: a variant (possibly prefixed by its run) and its cells, one per column.
#[derive(Clone, Debug, PartialEq)]
pub struct HeatRow {
    pub label: String,
    pub cells: Vec<Option<HeatCell>>,
}

/// The heatmap's content.
#[derive(Clone, Debug, PartialEq)]
pub struct Heatmap {
    pub title: String,
    pub columns: Vec<String>,
    pub rows: Vec<HeatRow>,
}

/// A cell's size, pixels.
pub const CELL_W_PX: usize = 92;
pub const CELL_H_PX: usize = 46;
const TOP_PX: usize = 44;
const LABEL_CHARS: usize = 26;

/// The sequential scale, low to high (viridis' stops: colour-blind safe, and light where the
/// rate is high so failures stand out dark).
const SCALE: [Rgb; 5] = [
    [68, 1, 84],
    [59, 82, 139],
    [33, 145, 140],
    [94, 201, 98],
    [253, 231, 37],
];

/// The colour of `rate` (0..1) on the scale.
pub fn colour_of(rate: f64) -> Rgb {
    let t = rate.clamp(0.0, 1.0) * (SCALE.len() - 1) as f64;
    let i = (t.floor() as usize).min(SCALE.len() - 2);
    let f = t - i as f64;
    std::array::from_fn(|c| {
        let (a, b) = (f64::from(SCALE[i][c]), f64::from(SCALE[i + 1][c]));
        (a + (b - a) * f).round() as u8
    })
}

/// Black or white, whichever reads on `background`.
fn ink_on(background: Rgb) -> Rgb {
    let [r, g, b] = background.map(f64::from);
    if 0.299 * r + 0.587 * g + 0.114 * b > 140.0 {
        BLACK
    } else {
        WHITE
    }
}

/// The left edge of column `c` given the label column's width.
pub fn column_x(left_px: usize, c: usize) -> usize {
    left_px + c * CELL_W_PX
}

/// The top of row `r`.
pub fn row_y(r: usize) -> usize {
    TOP_PX + r * CELL_H_PX
}

/// The label column's width, pixels.
pub fn left_px(map: &Heatmap) -> usize {
    let chars = (map.rows.iter())
        .map(|r| r.label.chars().count().min(LABEL_CHARS))
        .max()
        .unwrap_or(4);
    chars * GLYPH_PX + 16
}

/// Draws the heatmap.
pub fn heatmap(map: &Heatmap) -> Canvas {
    let left = left_px(map);
    let width = (column_x(left, map.columns.len()) + 16).max(360);
    let legend_y = row_y(map.rows.len()) + 14;
    let height = legend_y + 40;
    let mut canvas = Canvas::new(width, height, WHITE);
    canvas.text(8, 8, &fit(&map.title, (width - 16) / GLYPH_PX), 1, BLACK);
    for (c, column) in map.columns.iter().enumerate() {
        let centre = column_x(left, c) + CELL_W_PX / 2;
        canvas.text_centred(centre, TOP_PX - 14, &fit(column, 11), 1, BLACK);
    }
    for (r, row) in map.rows.iter().enumerate() {
        let y = row_y(r);
        canvas.text(
            8,
            y + CELL_H_PX / 2 - 4,
            &fit(&row.label, LABEL_CHARS),
            1,
            BLACK,
        );
        for (c, cell) in row.cells.iter().enumerate() {
            let x = column_x(left, c);
            let Some(cell) = cell else {
                canvas.fill(x + 1, y + 1, x + CELL_W_PX - 1, y + CELL_H_PX - 1, GREY);
                canvas.text_centred(x + CELL_W_PX / 2, y + CELL_H_PX / 2 - 4, "-", 1, DARK);
                continue;
            };
            let background = colour_of(cell.rate.value);
            let ink = ink_on(background);
            canvas.fill(
                x + 1,
                y + 1,
                x + CELL_W_PX - 1,
                y + CELL_H_PX - 1,
                background,
            );
            let centre = x + CELL_W_PX / 2;
            let rate = format!("{:.0}%", 100.0 * cell.rate.value);
            canvas.text_centred(centre, y + 4, &rate, 2, ink);
            let interval = format!(
                "[{:.0}-{:.0}]",
                100.0 * cell.rate.low,
                100.0 * cell.rate.high
            );
            canvas.text_centred(centre, y + 23, &interval, 1, ink);
            if let Some(drop) = cell.drop {
                let points = (-100.0 * drop).round();
                let change = if points == 0.0 {
                    "+-0 pts".to_string()
                } else {
                    format!("{points:+.0} pts")
                };
                canvas.text_centred(centre, y + 34, &change, 1, ink);
            }
        }
    }
    // The scale: 0 % to 100 %, labelled at its ends and middle.
    let (x0, x1) = (left, left + 200.min(width - left - 8));
    for x in x0..x1 {
        let rate = (x - x0) as f64 / (x1 - x0 - 1).max(1) as f64;
        canvas.vline(x, legend_y, legend_y + 10, colour_of(rate));
    }
    canvas.text(8, legend_y + 1, "success", 1, BLACK);
    canvas.text(x0, legend_y + 14, "0%", 1, BLACK);
    canvas.text_centred((x0 + x1) / 2, legend_y + 14, "50%", 1, BLACK);
    canvas.text(x1.saturating_sub(32), legend_y + 14, "100%", 1, BLACK);
    canvas
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn cells_are_coloured_by_rate_and_labelled() {
        let cell = |value: f64, drop| {
            Some(HeatCell {
                rate: Rate {
                    value,
                    low: (value - 0.1).max(0.0),
                    high: (value + 0.1).min(1.0),
                },
                drop,
            })
        };
        let map = Heatmap {
            title: "expert".into(),
            columns: vec!["T1-1".into(), "T1-2".into(), "mean".into()],
            rows: vec![
                HeatRow {
                    label: "none".into(),
                    cells: vec![cell(1.0, None), cell(0.9, None), cell(0.95, None)],
                },
                HeatRow {
                    label: "smoke=2".into(),
                    cells: vec![cell(0.0, Some(1.0)), None, cell(0.0, Some(1.0))],
                },
            ],
        };
        let canvas = heatmap(&map);
        let left = left_px(&map);
        // A cell's corner shows its colour; 0 % is dark, 100 % light, a missing cell grey.
        let corner = |r, c| canvas.at(column_x(left, c) + 3, row_y(r) + 3).unwrap();
        assert_eq!(corner(0, 0), colour_of(1.0));
        assert_eq!(corner(1, 0), colour_of(0.0));
        assert_eq!(corner(1, 1), GREY);
        assert_ne!(colour_of(0.0), colour_of(1.0));
        // Each cell carries ink of the contrasting colour (its labels).
        for (r, c) in [(0, 0), (1, 0)] {
            let (x, y) = (column_x(left, c), row_y(r));
            let background = corner(r, c);
            let ink = ink_on(background);
            let inked = (y..y + CELL_H_PX)
                .flat_map(|y| (x..x + CELL_W_PX).map(move |x| (x, y)))
                .filter(|&(x, y)| canvas.at(x, y) == Some(ink))
                .count();
            assert!(inked > 100, "cell ({r}, {c}) has {inked} inked pixels");
        }
        // The drop's line is drawn only on perturbed rows.
        let third_line = |r: usize| {
            let (x, y) = (column_x(left, 0), row_y(r) + 34);
            let ink = ink_on(corner(r, 0));
            (y..y + 8)
                .flat_map(|y| (x..x + CELL_W_PX).map(move |x| (x, y)))
                .filter(|&(x, y)| canvas.at(x, y) == Some(ink))
                .count()
        };
        assert_eq!(third_line(0), 0);
        assert!(third_line(1) > 20);
    }
}

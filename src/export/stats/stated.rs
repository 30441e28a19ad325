//! A feature's statistics as LeRobot states them ([`Stated`]): min, max, mean, std, the count
//! and the quantiles, each per vector element or per image channel, before they become JSON or
//! another table's cells. Every kind of statistics states itself this way; the JSON is made
//! from it in one place.

use serde_json::{Value, json};

/// A feature's statistics, per vector element or per image channel.
#[derive(Clone, Debug, PartialEq)]
pub struct Stated {
    /// An image's: each value is stated nested (C, 1, 1), as LeRobot states images.
    pub image: bool,
    /// min, max, mean and std.
    pub moments: [Vec<f64>; 4],
    /// Frames (images) or values (vectors) counted.
    pub count: u64,
    /// The quantiles known, each named as in [`super::QUANTILES`], in that order.
    pub quantiles: Vec<(&'static str, Vec<f64>)>,
}

/// The names of [`Stated::moments`], in order.
pub const MOMENTS: [&str; 4] = ["min", "max", "mean", "std"];

impl Stated {
    /// As LeRobot's JSON: min, max, mean, std, count, then the quantiles (a value JSON cannot
    /// hold, such as NaN, is null).
    pub fn to_json(&self) -> Value {
        let shape = |values: &[f64]| -> Value {
            if self.image {
                json!(values.iter().map(|v| [[*v]]).collect::<Vec<_>>())
            } else {
                json!(values)
            }
        };
        let mut out = serde_json::Map::new();
        for (name, values) in MOMENTS.iter().zip(&self.moments) {
            out.insert((*name).into(), shape(values));
        }
        out.insert("count".into(), json!([self.count]));
        for (name, values) in &self.quantiles {
            out.insert((*name).into(), shape(values));
        }
        Value::Object(out)
    }
}

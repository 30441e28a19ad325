//! Procedural organ shapes, deterministic from a seed: a kidney (bean with a hilum), a spleen
//! (flattened crescent with notched margins) and a vessel segment (a gently winding tube).
//!
//! Each solid organ is star-shaped about its centre: [`surface_point`] maps a direction to the
//! surface point, so meshes, collision hulls and marks placed on the surface all agree. Every
//! organ has a flattened base where it rests on the tray (at `-0.7` of its z semi-axis).

use crate::noise::value_noise3;
use crate::scene::{OrganKind, OrganSpec};
use nalgebra::Vector3;

/// Where the flattened base sits, as a fraction of the z semi-axis below the centre.
pub const BASE_FRACTION: f64 = 0.7;

fn seed32(seed: u64) -> u32 {
    (seed ^ (seed >> 32)) as u32
}

/// Surface point (organ frame) in unit direction `d` for a kidney or spleen.
pub fn surface_point(spec: &OrganSpec, d: Vector3<f64>) -> Vector3<f64> {
    let d = d.try_normalize(1e-12).unwrap_or(Vector3::z());
    let [a, b, c] = spec.semi_axes_m;
    let ellipsoid = 1.0 / ((d.x / a).powi(2) + (d.y / b).powi(2) + (d.z / c).powi(2)).sqrt();
    let seed = seed32(spec.shape_seed);
    let noise = |scale: f64, s: u32| {
        f64::from(value_noise3(
            [
                (d.x * scale) as f32,
                (d.y * scale) as f32,
                (d.z * scale) as f32,
            ],
            seed ^ s,
        ))
    };
    let mut p = match spec.kind {
        OrganKind::Kidney => {
            // The hilum: an indentation on the medial (-x) side.
            let hilum = Vector3::new(-1.0, 0.0, 0.15).normalize();
            let angle = d.dot(&hilum).clamp(-1.0, 1.0).acos();
            let dent = 0.32 * (-(angle / 0.55).powi(2)).exp();
            d * ellipsoid * (1.0 - dent) * (1.0 + 0.05 * noise(2.2, 1) + 0.015 * noise(6.0, 2))
        }
        OrganKind::Spleen => {
            let mut p = d * ellipsoid * (1.0 + 0.04 * noise(2.0, 3) + 0.02 * noise(7.0, 4));
            // Crescent: the long (y) ends curl toward -x; notches along the margin.
            p.x -= 0.45 * a * (p.y / b).powi(2);
            let margin = (1.0 - (d.z * d.z)).max(0.0);
            p *= 1.0
                - 0.06 * margin * (0.5 + 0.5 * (d.y * 14.0 + noise(1.0, 5) * 2.0).sin()).powi(4);
            p
        }
        OrganKind::Vessel => d * ellipsoid,
    };
    p.z = p.z.max(-BASE_FRACTION * c);
    p
}

/// How far `point_m` (world) lies outside a kidney's or spleen's surface along the ray from the
/// organ's centre (negative: inside it), metres. On the organ's upper side, where a tool touches
/// it, the ray runs close to the surface normal; a mark placed on the surface is at 0.
pub fn radial_gap_m(spec: &OrganSpec, point_m: &Vector3<f64>) -> f64 {
    let local = spec
        .world_from_organ
        .inverse_transform_point(&nalgebra::Point3::from(*point_m))
        .coords;
    let direction = local.try_normalize(1e-12).unwrap_or(Vector3::z());
    let surface = surface_point(spec, direction);
    // The surface point lies on the ray except where the shape bends it (the spleen's crescent):
    // measure along the ray to the surface point's projection on it.
    local.norm() - surface.dot(&direction)
}

/// The vessel's centre line (organ frame) and tube radius: it runs along y, winding in x.
pub fn vessel_path(spec: &OrganSpec, points: usize) -> (Vec<Vector3<f64>>, f64) {
    let [wiggle, half_length, radius] = spec.semi_axes_m;
    let seed = seed32(spec.shape_seed);
    let phase = f64::from(value_noise3([0.5, 0.5, 0.5], seed)) * 3.0;
    let n = points.max(2);
    let path = (0..n)
        .map(|i| {
            let t = i as f64 / (n - 1) as f64;
            let y = -half_length + 2.0 * half_length * t;
            let x = wiggle * (std::f64::consts::PI * 1.3 * t + phase).sin();
            Vector3::new(x, y, 0.0)
        })
        .collect();
    (path, radius)
}

/// Points of the vessel's centre line [`vessel_section`] measures against (the drawn tube has 48).
const VESSEL_SECTION_POINTS: usize = 97;

/// Where a point lies relative to the vessel's tube, in the cross-section through the nearest
/// point of its centre line, metres.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct VesselSection {
    /// Horizontal distance from the centre line, signed (positive on the side of the centre
    /// line's left normal, looking along the vessel).
    pub across_m: f64,
    /// Height above the centre line.
    pub above_axis_m: f64,
    /// Distance along the centre line from its start.
    pub along_m: f64,
    pub radius_m: f64,
}

impl VesselSection {
    /// Inside the tube.
    pub fn inside(&self) -> bool {
        self.across_m.hypot(self.above_axis_m) < self.radius_m
    }
}

/// Where `point_m` (world) lies relative to the vessel `spec`'s tube.
pub fn vessel_section(spec: &OrganSpec, point_m: &Vector3<f64>) -> VesselSection {
    let local = spec
        .world_from_organ
        .inverse_transform_point(&nalgebra::Point3::from(*point_m))
        .coords;
    let (path, radius_m) = vessel_path(spec, VESSEL_SECTION_POINTS);
    // (horizontal distance squared, arc length, foot of the perpendicular, unit tangent)
    let mut best = (f64::INFINITY, 0.0, path[0], Vector3::y());
    let mut walked = 0.0;
    for pair in path.windows(2) {
        let segment = pair[1] - pair[0];
        let length = segment.norm();
        let t = ((local - pair[0]).dot(&segment) / (length * length)).clamp(0.0, 1.0);
        let foot = pair[0] + segment * t;
        let d2 = (local.xy() - foot.xy()).norm_squared();
        if d2 < best.0 {
            best = (d2, walked + t * length, foot, segment / length);
        }
        walked += length;
    }
    let (_, along_m, foot, tangent) = best;
    let left = Vector3::new(-tangent.y, tangent.x, 0.0);
    let offset = local - foot;
    VesselSection {
        across_m: offset.x * left.x + offset.y * left.y,
        above_axis_m: offset.z,
        along_m,
        radius_m,
    }
}

/// Rings and segments of the sampling grid of a solid organ's surface (drawn and collided).
pub const SURFACE_GRID: (usize, usize) = (22, 44);

/// The unit directions of a `rings` x `segments` sphere grid: north pole, rings from north to
/// south, south pole (the vertex order of the renderer's star-shaped meshes).
pub fn grid_directions(rings: usize, segments: usize) -> Vec<Vector3<f32>> {
    use std::f32::consts::{PI, TAU};
    let (rings, segments) = (rings.max(2), segments.max(3));
    let mut directions = vec![Vector3::z()];
    for r in 1..rings {
        let polar = PI * r as f32 / rings as f32;
        for s in 0..segments {
            let azimuth = TAU * s as f32 / segments as f32;
            directions.push(Vector3::new(
                polar.sin() * azimuth.cos(),
                polar.sin() * azimuth.sin(),
                polar.cos(),
            ));
        }
    }
    directions.push(-Vector3::z());
    directions
}

/// A solid organ's surface point (organ frame, f32) in grid direction `d`.
pub fn surface_point_f32(spec: &OrganSpec, d: Vector3<f32>) -> Vector3<f32> {
    surface_point(spec, d.map(f64::from)).map(|v| v as f32)
}

/// The surface points of a solid organ on [`SURFACE_GRID`]: the drawn mesh's vertices, whose
/// convex hull is its collision shape.
pub fn surface_samples(spec: &OrganSpec) -> Vec<Vector3<f32>> {
    let (rings, segments) = SURFACE_GRID;
    grid_directions(rings, segments)
        .into_iter()
        .map(|d| surface_point_f32(spec, d))
        .collect()
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Isometry3;

    fn spec(kind: OrganKind, seed: u64) -> OrganSpec {
        OrganSpec {
            kind,
            world_from_organ: Isometry3::identity(),
            semi_axes_m: [0.027, 0.048, 0.018],
            shape_seed: seed,
        }
    }

    #[test]
    fn shapes_vary_with_the_seed_and_repeat_with_it() {
        let d = Vector3::new(0.3, 0.5, 0.8);
        for kind in [OrganKind::Kidney, OrganKind::Spleen] {
            assert_eq!(
                surface_point(&spec(kind, 1), d),
                surface_point(&spec(kind, 1), d)
            );
            assert_ne!(
                surface_point(&spec(kind, 1), d),
                surface_point(&spec(kind, 2), d)
            );
        }
    }

    #[test]
    fn kidney_keeps_its_proportions_and_a_flat_base() {
        let kidney = spec(OrganKind::Kidney, 3);
        let length =
            surface_point(&kidney, Vector3::y()).y - surface_point(&kidney, -Vector3::y()).y;
        assert!((length - 0.096).abs() < 0.012, "length {length}");
        let bottom = surface_point(&kidney, -Vector3::z()).z;
        assert!((bottom + BASE_FRACTION * 0.018).abs() < 1e-12);
        // The hilum side is indented relative to the convex side.
        let medial = -surface_point(&kidney, -Vector3::x()).x;
        let lateral = surface_point(&kidney, Vector3::x()).x;
        assert!(medial < 0.8 * lateral, "medial {medial} lateral {lateral}");
    }
}

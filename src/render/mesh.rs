//! Triangle meshes (f32, counter-clockwise front faces, per-vertex normals) and the primitive
//! builders the procedural assets are made of: boxes, height-field slabs, cylinders, tubes along
//! a path, and star-shaped spheres (`r = f(direction)`).

use nalgebra::{Isometry3, Point3, Vector3};
use std::f32::consts::{PI, TAU};

/// An indexed triangle mesh in its own frame, metres.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct Mesh {
    pub positions: Vec<[f32; 3]>,
    pub normals: Vec<[f32; 3]>,
    pub triangles: Vec<[u32; 3]>,
    /// Per-vertex brightness factor baked from a pattern (empty = 1 everywhere).
    pub shade: Vec<f32>,
}

fn v3(p: [f32; 3]) -> Vector3<f32> {
    Vector3::new(p[0], p[1], p[2])
}

impl Mesh {
    /// A mesh with smooth (area-weighted) vertex normals.
    pub fn smooth(positions: Vec<[f32; 3]>, triangles: Vec<[u32; 3]>) -> Self {
        let mut normals = vec![Vector3::<f32>::zeros(); positions.len()];
        for t in &triangles {
            let [a, b, c] = t.map(|i| v3(positions[i as usize]));
            let n = (b - a).cross(&(c - a));
            for i in t {
                normals[*i as usize] += n;
            }
        }
        let normals = normals
            .into_iter()
            .map(|n| n.try_normalize(1e-20).unwrap_or(Vector3::z()).into())
            .collect();
        Mesh {
            positions,
            normals,
            triangles,
            shade: Vec::new(),
        }
    }

    /// Bakes a material's 3-D mottling into per-vertex shade factors and returns the material
    /// to draw with (its pattern then solid): dense curved meshes get texture detail at no cost
    /// per pixel.
    pub fn bake(
        &mut self,
        material: crate::render::material::Material,
    ) -> crate::render::material::Material {
        use crate::render::material::{Pattern, mottling3};
        if !matches!(material.pattern, Pattern::Mottled { .. }) {
            return material;
        }
        self.shade = self
            .positions
            .iter()
            .map(|p| mottling3(&material.pattern, *p))
            .collect();
        material.with_pattern(Pattern::Solid)
    }

    pub fn triangle_count(&self) -> usize {
        self.triangles.len()
    }

    /// Appends `other` placed by `pose` (normals rotated).
    pub fn append(&mut self, other: &Mesh, pose: &Isometry3<f32>) {
        let offset = self.positions.len() as u32;
        self.positions.extend(
            other
                .positions
                .iter()
                .map(|p| -> [f32; 3] { (pose * Point3::from(*p)).coords.into() }),
        );
        self.normals.extend(
            other
                .normals
                .iter()
                .map(|n| -> [f32; 3] { (pose.rotation * v3(*n)).into() }),
        );
        self.triangles
            .extend(other.triangles.iter().map(|t| t.map(|i| i + offset)));
    }

    /// Axis-aligned box with flat faces, centred at the origin.
    pub fn cuboid(half: [f32; 3]) -> Self {
        let mut mesh = Mesh::default();
        let [hx, hy, hz] = half;
        // (normal, u axis, v axis) per face; corners n + -u -v, n + u -v, n + u v, n - u v.
        let faces: [([f32; 3], [f32; 3], [f32; 3]); 6] = [
            ([1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]),
            ([-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]),
            ([0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 0.0, 0.0]),
            ([0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]),
            ([0.0, 0.0, 1.0], [1.0, 0.0, 0.0], [0.0, 1.0, 0.0]),
            ([0.0, 0.0, -1.0], [0.0, 1.0, 0.0], [1.0, 0.0, 0.0]),
        ];
        for (n, u, v) in faces {
            let base = mesh.positions.len() as u32;
            for (su, sv) in [(-1.0, -1.0), (1.0, -1.0), (1.0, 1.0), (-1.0, 1.0)] {
                let p = [0, 1, 2].map(|k| (n[k] + su * u[k] + sv * v[k]) * [hx, hy, hz][k]);
                mesh.positions.push(p);
                mesh.normals.push(n);
            }
            mesh.triangles.push([base, base + 1, base + 2]);
            mesh.triangles.push([base, base + 2, base + 3]);
        }
        mesh
    }

    /// A closed slab over `[-hx, hx] x [-hy, hy]`: a flat bottom at `-hz`, a top at
    /// `hz + height(x, y)` sampled on an `nx` x `ny` grid, and side walls.
    pub fn slab(half: [f32; 3], nx: usize, ny: usize, height: impl Fn(f32, f32) -> f32) -> Self {
        let [hx, hy, hz] = half;
        let (nx, ny) = (nx.max(1), ny.max(1));
        let mut positions = Vec::new();
        let mut triangles = Vec::new();
        let index = |i: usize, j: usize| (j * (nx + 1) + i) as u32;
        for j in 0..=ny {
            for i in 0..=nx {
                let x = -hx + 2.0 * hx * i as f32 / nx as f32;
                let y = -hy + 2.0 * hy * j as f32 / ny as f32;
                positions.push([x, y, hz + height(x, y)]);
            }
        }
        for j in 0..ny {
            for i in 0..nx {
                triangles.push([index(i, j), index(i + 1, j), index(i + 1, j + 1)]);
                triangles.push([index(i, j), index(i + 1, j + 1), index(i, j + 1)]);
            }
        }
        let mut mesh = Mesh::smooth(positions, triangles);
        // Bottom and walls as flat-shaded quads following the top's border.
        let border: Vec<(usize, usize)> = (0..nx)
            .map(|i| (i, 0))
            .chain((0..ny).map(|j| (nx, j)))
            .chain((0..nx).map(|i| (nx - i, ny)))
            .chain((0..ny).map(|j| (0, ny - j)))
            .collect();
        for k in 0..border.len() {
            let (i0, j0) = border[k];
            let (i1, j1) = border[(k + 1) % border.len()];
            let top0 = mesh.positions[index(i0, j0) as usize];
            let top1 = mesh.positions[index(i1, j1) as usize];
            let bottom0 = [top0[0], top0[1], -hz];
            let bottom1 = [top1[0], top1[1], -hz];
            let outward = v3(top1) - v3(top0);
            let n = Vector3::new(outward.y, -outward.x, 0.0).normalize();
            mesh.push_quad([bottom0, bottom1, top1, top0], n.into());
        }
        mesh.push_quad(
            [
                [-hx, hy, -hz],
                [hx, hy, -hz],
                [hx, -hy, -hz],
                [-hx, -hy, -hz],
            ],
            [0.0, 0.0, -1.0],
        );
        mesh
    }

    /// A flat-shaded quad (counter-clockwise seen from `normal`).
    pub fn push_quad(&mut self, corners: [[f32; 3]; 4], normal: [f32; 3]) {
        let base = self.positions.len() as u32;
        for c in corners {
            self.positions.push(c);
            self.normals.push(normal);
        }
        self.triangles.push([base, base + 1, base + 2]);
        self.triangles.push([base, base + 2, base + 3]);
    }

    /// A cylinder (or cone frustum) along z from `z0` to `z1` with end radii, optional caps.
    pub fn cylinder(
        radius0: f32,
        radius1: f32,
        z0: f32,
        z1: f32,
        segments: usize,
        caps: bool,
    ) -> Self {
        let path = [[0.0, 0.0, z0], [0.0, 0.0, z1]];
        Mesh::tube(&path, &[radius0, radius1], segments, caps)
    }

    /// A tube of varying radius along a polyline (parallel-transported frames), optional caps.
    pub fn tube(path: &[[f32; 3]], radii: &[f32], segments: usize, caps: bool) -> Self {
        let segments = segments.max(3);
        let n = path.len();
        let mut positions = Vec::with_capacity(n * segments + 2);
        let mut triangles = Vec::new();
        if n < 2 {
            return Mesh::default();
        }
        let tangent = |i: usize| {
            let a = v3(path[i.saturating_sub(1)]);
            let b = v3(path[(i + 1).min(n - 1)]);
            (b - a).try_normalize(1e-20).unwrap_or(Vector3::z())
        };
        let t0 = tangent(0);
        let helper = if t0.x.abs() < 0.9 {
            Vector3::x()
        } else {
            Vector3::y()
        };
        let mut normal = t0.cross(&helper).normalize();
        for i in 0..n {
            let t = tangent(i);
            normal = (normal - t * normal.dot(&t))
                .try_normalize(1e-20)
                .unwrap_or(normal);
            let binormal = t.cross(&normal);
            let radius = radii[i.min(radii.len() - 1)];
            for s in 0..segments {
                let a = TAU * s as f32 / segments as f32;
                let offset = normal * a.cos() + binormal * a.sin();
                positions.push((v3(path[i]) + offset * radius).into());
            }
        }
        for i in 0..n - 1 {
            for s in 0..segments {
                let a = (i * segments + s) as u32;
                let b = (i * segments + (s + 1) % segments) as u32;
                let c = a + segments as u32;
                let d = b + segments as u32;
                triangles.push([a, b, d]);
                triangles.push([a, d, c]);
            }
        }
        if caps {
            for (ring, sign) in [(0usize, -1.0f32), (n - 1, 1.0)] {
                let centre = positions.len() as u32;
                positions.push(path[ring]);
                for s in 0..segments {
                    let a = (ring * segments + s) as u32;
                    let b = (ring * segments + (s + 1) % segments) as u32;
                    triangles.push(if sign > 0.0 {
                        [centre, a, b]
                    } else {
                        [centre, b, a]
                    });
                }
            }
        }
        Mesh::smooth(positions, triangles)
    }

    /// A closed star-shaped surface: the unit sphere's direction `d` maps to `point(d)`.
    /// `rings` latitude bands and `segments` longitudes.
    pub fn star(
        rings: usize,
        segments: usize,
        point: impl Fn(Vector3<f32>) -> Vector3<f32>,
    ) -> Self {
        let (rings, segments) = (rings.max(2), segments.max(3));
        let mut positions = vec![point(Vector3::z()).into()];
        for r in 1..rings {
            let polar = PI * r as f32 / rings as f32;
            for s in 0..segments {
                let azimuth = TAU * s as f32 / segments as f32;
                let d = Vector3::new(
                    polar.sin() * azimuth.cos(),
                    polar.sin() * azimuth.sin(),
                    polar.cos(),
                );
                positions.push(point(d).into());
            }
        }
        positions.push(point(-Vector3::z()).into());
        let south = (positions.len() - 1) as u32;
        let ring = |r: usize, s: usize| (1 + (r - 1) * segments + s % segments) as u32;
        let mut triangles = Vec::new();
        for s in 0..segments {
            triangles.push([0, ring(1, s), ring(1, s + 1)]);
            triangles.push([south, ring(rings - 1, s + 1), ring(rings - 1, s)]);
        }
        for r in 1..rings - 1 {
            for s in 0..segments {
                triangles.push([ring(r, s), ring(r + 1, s), ring(r + 1, s + 1)]);
                triangles.push([ring(r, s), ring(r + 1, s + 1), ring(r, s + 1)]);
            }
        }
        Mesh::smooth(positions, triangles)
    }

    /// A sphere of `radius`.
    pub fn sphere(radius: f32, rings: usize, segments: usize) -> Self {
        Mesh::star(rings, segments, |d| d * radius)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Signed volume by the divergence theorem: positive for outward-facing closed meshes.
    fn volume(mesh: &Mesh) -> f32 {
        mesh.triangles
            .iter()
            .map(|t| {
                let [a, b, c] = t.map(|i| v3(mesh.positions[i as usize]));
                a.dot(&b.cross(&c)) / 6.0
            })
            .sum()
    }

    #[test]
    fn closed_primitives_face_outward_with_the_right_volume() {
        assert!((volume(&Mesh::cuboid([1.0, 2.0, 3.0])) - 48.0).abs() < 1e-4);
        let sphere = volume(&Mesh::sphere(1.0, 32, 64));
        assert!((sphere - 4.0 / 3.0 * PI).abs() < 0.05, "{sphere}");
        let cylinder = volume(&Mesh::cylinder(1.0, 1.0, 0.0, 2.0, 64, true));
        assert!((cylinder - 2.0 * PI).abs() < 0.05, "{cylinder}");
        let slab = volume(&Mesh::slab([1.0, 1.0, 0.5], 4, 4, |_, _| 0.0));
        assert!((slab - 4.0).abs() < 1e-4, "{slab}");
    }

    #[test]
    fn append_offsets_indices() {
        let mut mesh = Mesh::cuboid([1.0; 3]);
        let n = mesh.positions.len() as u32;
        mesh.append(
            &Mesh::cuboid([1.0; 3]),
            &Isometry3::translation(5.0, 0.0, 0.0),
        );
        assert_eq!(mesh.triangle_count(), 24);
        assert!(
            mesh.triangles[12..]
                .iter()
                .all(|t| t.iter().all(|i| *i >= n))
        );
        assert!((mesh.positions[n as usize][0] - 6.0).abs() < 1e-6);
    }
}

//! The CPU rasterizer: a visibility pass into a G-buffer, then one shading pass per pixel.
//!
//! Visibility: every triangle is moved to the camera's optical frame, optionally back-face
//! culled, clipped against the near plane (Sutherland-Hodgman; crossing triangles are cut, not
//! dropped), projected, snapped to 1/256 pixel and scanned with integer edge functions at pixel
//! centres. The fill rule gives a shared edge to exactly one of its two triangles, so meshes
//! are watertight (no cracks, no double hits). Depth is the distance along the optical axis,
//! interpolated perspective-correctly (1/z is linear in screen space); the G-buffer keeps the
//! nearest surface's instance, triangle and perspective-correct barycentrics.
//!
//! Shading: the light sits at the camera (an endoscope's light guide surrounds its lens) and falls
//! off with the square of the distance; Lambert diffuse plus a Blinn-Phong highlight (with the
//! light at the eye the half vector is the view vector), a procedural pattern, and a vignette.

use crate::render::camera::Camera;
use crate::render::material::{Material, Pattern, srgb_table};
use crate::render::mesh::Mesh;
use nalgebra::{Isometry3, Point3, Vector3};

/// Instance id of pixels that show no surface.
const NO_INSTANCE: u16 = u16::MAX;
/// Sub-pixel precision of the edge functions: 1/256 pixel.
const SUBPIXEL: f64 = 256.0;
/// Projected coordinates are kept within this many pixels so that products fit in i64.
const GUARD_BAND_PX: f64 = 1.0e6;

/// One mesh placed in the world with a material and a mask id.
#[derive(Clone, Copy, Debug)]
pub struct Instance<'a> {
    pub mesh: &'a Mesh,
    pub world_from_mesh: Isometry3<f64>,
    pub material: Material,
    /// The value written to the segmentation mask where this instance is visible.
    pub mask_id: u8,
    /// Skip triangles facing away from the camera (only safe for closed meshes).
    pub cull_back_faces: bool,
}

/// The endoscope's light and lens.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct Lighting {
    /// Irradiance gain at `reference_distance_m` (1 = albedo shows as is when facing the light).
    pub light_gain: f32,
    pub reference_distance_m: f32,
    /// Largest irradiance factor very close to the lens (keeps near surfaces from blowing out).
    pub max_irradiance: f32,
    /// Light that reaches everything regardless of orientation (scatter in the cavity).
    pub ambient: f32,
    /// Darkening at the image corners: factor `1 - vignette * r^2`, r = 1 at a corner.
    pub vignette: f32,
    /// Colour where no surface is within the far plane, linear RGB.
    pub background: [f32; 3],
    /// Honour materials lit per vertex (false: every surface lit per pixel, slower).
    pub allow_per_vertex: bool,
}

impl Default for Lighting {
    fn default() -> Self {
        Lighting {
            light_gain: 1.25,
            reference_distance_m: 0.14,
            max_irradiance: 3.0,
            ambient: 0.06,
            vignette: 0.35,
            background: [0.012, 0.004, 0.004],
            allow_per_vertex: true,
        }
    }
}

/// What a render produces, row-major from the top-left pixel.
#[derive(Clone, Debug, PartialEq)]
pub struct Frame {
    pub width_px: u32,
    pub height_px: u32,
    /// RGB u8, 3 bytes a pixel, sRGB.
    pub rgb: Vec<u8>,
    /// Distance along the optical axis, metres; 0 where no surface lies within the far plane.
    pub depth_m: Vec<f32>,
    /// Mask ids; 0 where no surface is visible.
    pub mask: Vec<u8>,
}

/// A reusable rasterizer: buffers are kept between frames.
#[derive(Debug, Default)]
pub struct Rasterizer {
    /// 1 / depth of the nearest surface so far (0 = nothing).
    inv_depth: Vec<f32>,
    instance: Vec<u16>,
    triangle: Vec<u32>,
    bary: Vec<[f32; 2]>,
    camera_positions: Vec<[f32; 3]>,
    camera_normals: Vec<[f32; 3]>,
    /// Linear colour lit at each vertex (instances lit per vertex only).
    vertex_colours: Vec<[f32; 3]>,
    vertex_offsets: Vec<usize>,
    /// The static instances' layer kept by [`Rasterizer::render_over_static`].
    layer: Option<StaticLayer>,
    /// Where the G-buffer differs from the kept layer's.
    changed: Changed,
    /// Frames leave the mask empty (see [`super::RenderOptions::mask`]).
    pub(super) skip_mask: bool,
    /// Buffers of frames handed back ([`Rasterizer::recycle`]) for the next layered frames.
    spare: Vec<(Vec<u8>, Vec<f32>, Vec<u8>)>,
}

/// Where the G-buffer differs from the kept static layer's.
#[derive(Clone, Copy, Debug, Default, PartialEq)]
enum Changed {
    /// Anywhere (drawn without the layer, or never drawn).
    #[default]
    Anywhere,
    /// Only inside this rectangle.
    Within(PixelRect),
    /// Nowhere.
    Nowhere,
}

/// An inclusive rectangle of pixels.
#[derive(Clone, Copy, Debug, PartialEq)]
struct PixelRect {
    x0: usize,
    x1: usize,
    y0: usize,
    y1: usize,
}

impl PixelRect {
    /// The smallest rectangle holding both.
    fn union(self, other: PixelRect) -> PixelRect {
        PixelRect {
            x0: self.x0.min(other.x0),
            x1: self.x1.max(other.x1),
            y0: self.y0.min(other.y0),
            y1: self.y1.max(other.y1),
        }
    }
}

/// What a static layer was drawn from.
#[derive(Clone, Debug, PartialEq)]
struct StaticKey {
    camera: Camera,
    lighting: Lighting,
    instances: Vec<StaticInstance>,
}

/// One static instance as a layer saw it: the mesh's address and sizes, and everything else.
#[derive(Clone, Debug, PartialEq)]
struct StaticInstance {
    mesh_address: usize,
    positions: usize,
    triangles: usize,
    world_from_mesh: Isometry3<f64>,
    material: Material,
    mask_id: u8,
    cull_back_faces: bool,
}

impl StaticInstance {
    fn of(instance: &Instance<'_>) -> Self {
        StaticInstance {
            mesh_address: std::ptr::from_ref(instance.mesh) as usize,
            positions: instance.mesh.positions.len(),
            triangles: instance.mesh.triangles.len(),
            world_from_mesh: instance.world_from_mesh,
            material: instance.material,
            mask_id: instance.mask_id,
            cull_back_faces: instance.cull_back_faces,
        }
    }
}

/// The edge function of `a -> b` at `p` (fixed point): twice the signed area of (a, b, p).
#[inline(always)]
fn edge(a: (i64, i64), b: (i64, i64), p: (i64, i64)) -> i64 {
    (b.0 - a.0) * (p.1 - a.1) - (b.1 - a.1) * (p.0 - a.0)
}

/// A triangle's three edge functions (edge k opposite vertex k: 1 -> 2, 2 -> 0, 0 -> 1), for
/// stepping them over pixel centres.
struct Edges {
    /// The fill rule: -1 for edges that do not own the pixels on them (top-left rule).
    bias: [i64; 3],
    /// Change a pixel to the right, and a row down.
    step_x: [i64; 3],
    step_y: [i64; 3],
    /// Each biased edge function at `origin`.
    row: [i64; 3],
}

impl Edges {
    #[inline(always)]
    fn of(p: &[(i64, i64); 3], origin: (i64, i64)) -> Self {
        let step = SUBPIXEL as i64;
        let edges = [(p[1], p[2]), (p[2], p[0]), (p[0], p[1])];
        let bias = edges.map(|(a, b)| {
            let (dx, dy) = (b.0 - a.0, b.1 - a.1);
            if dy > 0 || (dy == 0 && dx < 0) { 0 } else { -1 }
        });
        let step_x = edges.map(|(a, b)| -(b.1 - a.1) * step);
        let step_y = edges.map(|(a, b)| (b.0 - a.0) * step);
        let row = [0usize, 1, 2].map(|k| edge(edges[k].0, edges[k].1, origin) + bias[k]);
        Edges {
            bias,
            step_x,
            step_y,
            row,
        }
    }
}

/// The span of a row (from `x0` to `x1`) where every biased edge function is >= 0, given each
/// edge's value `row` at `x0` and its step `step_x` a pixel; empty (`end < start`) when none.
#[inline(always)]
fn row_span(row: [i64; 3], step_x: [i64; 3], x0: i64, x1: i64) -> (i64, i64) {
    let (mut start, mut end) = (x0, x1);
    for k in 0..3 {
        let (w, s) = (row[k], step_x[k]);
        if s > 0 {
            if w < 0 {
                start = start.max(x0 + (-w + s - 1) / s);
            }
        } else if s < 0 {
            if w < 0 {
                end = x0 - 1;
            } else {
                end = end.min(x0 + w / -s);
            }
        } else if w < 0 {
            end = x0 - 1;
        }
    }
    (start, end)
}

impl StaticKey {
    fn of(camera: &Camera, lighting: &Lighting, instances: &[Instance<'_>]) -> Self {
        StaticKey {
            camera: *camera,
            lighting: *lighting,
            instances: instances.iter().map(StaticInstance::of).collect(),
        }
    }

    /// Whether this key is what [`StaticKey::of`] would make of these (compared in place:
    /// every frame asks, and nothing is allocated for it).
    fn describes(&self, camera: &Camera, lighting: &Lighting, instances: &[Instance<'_>]) -> bool {
        self.camera == *camera
            && self.lighting == *lighting
            && self.instances.len() == instances.len()
            && self
                .instances
                .iter()
                .zip(instances)
                .all(|(kept, instance)| *kept == StaticInstance::of(instance))
    }
}

/// The G-buffer and the sRGB pixels of the static instances alone.
#[derive(Debug)]
struct StaticLayer {
    key: StaticKey,
    inv_depth: Vec<f32>,
    instance: Vec<u16>,
    triangle: Vec<u32>,
    bary: Vec<[f32; 2]>,
    /// Camera-space vertices of the static instances.
    vertices: usize,
    rgb: Vec<u8>,
}

/// A clipped polygon vertex: camera-frame position and barycentrics in the original triangle.
#[derive(Clone, Copy, Debug)]
struct ClipVertex {
    position: [f32; 3],
    bary: [f32; 3],
}

fn lerp_clip(a: &ClipVertex, b: &ClipVertex, t: f32) -> ClipVertex {
    let mut out = *a;
    for k in 0..3 {
        out.position[k] = a.position[k] + (b.position[k] - a.position[k]) * t;
        out.bary[k] = a.bary[k] + (b.bary[k] - a.bary[k]) * t;
    }
    out
}

/// Clips a triangle to `z >= near`; returns the polygon (0, 3 or 4 vertices).
fn clip_near(input: [ClipVertex; 3], near: f32, out: &mut Vec<ClipVertex>) {
    out.clear();
    for i in 0..3 {
        let a = &input[i];
        let b = &input[(i + 1) % 3];
        let a_in = a.position[2] >= near;
        let b_in = b.position[2] >= near;
        if a_in {
            out.push(*a);
        }
        if a_in != b_in {
            // Interpolate from the inside vertex so both triangles sharing the edge agree.
            let (from, to) = if a_in { (a, b) } else { (b, a) };
            let t = (near - from.position[2]) / (to.position[2] - from.position[2]);
            let mut v = lerp_clip(from, to, t);
            v.position[2] = near;
            out.push(v);
        }
    }
}

/// Round half up without a libm call (the baseline x86-64 target has no rounding instruction).
#[inline]
fn round_i64(v: f64) -> i64 {
    let shifted = v + 0.5;
    let truncated = shifted as i64;
    if (truncated as f64) > shifted {
        truncated - 1
    } else {
        truncated
    }
}

fn sub(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [a[0] - b[0], a[1] - b[1], a[2] - b[2]]
}

fn cross(a: [f32; 3], b: [f32; 3]) -> [f32; 3] {
    [
        a[1] * b[2] - a[2] * b[1],
        a[2] * b[0] - a[0] * b[2],
        a[0] * b[1] - a[1] * b[0],
    ]
}

fn dot(a: [f32; 3], b: [f32; 3]) -> f32 {
    a[0] * b[0] + a[1] * b[1] + a[2] * b[2]
}

struct Target<'a> {
    width: i64,
    height: i64,
    fx: f64,
    fy: f64,
    cx: f64,
    cy: f64,
    near: f32,
    far: f32,
    inv_depth: &'a mut [f32],
    instance: &'a mut [u16],
    triangle: &'a mut [u32],
    bary: &'a mut [[f32; 2]],
    /// The bounding box of every triangle drawn so far (a superset of the pixels written).
    touched: Option<PixelRect>,
}

impl Target<'_> {
    /// The triangle's corners on the screen in fixed point (1/256 px, clamped to the guard
    /// band) and their inverse depths.
    #[inline(always)]
    fn project(&self, vertices: &[ClipVertex; 3]) -> ([(i64, i64); 3], [f32; 3]) {
        let mut fixed = [(0i64, 0i64); 3];
        let mut inv_z = [0f32; 3];
        for (k, v) in vertices.iter().enumerate() {
            let z = f64::from(v.position[2]);
            let sx = (self.fx * f64::from(v.position[0]) / z + self.cx)
                .clamp(-GUARD_BAND_PX, GUARD_BAND_PX);
            let sy = (self.fy * f64::from(v.position[1]) / z + self.cy)
                .clamp(-GUARD_BAND_PX, GUARD_BAND_PX);
            fixed[k] = (round_i64(sx * SUBPIXEL), round_i64(sy * SUBPIXEL));
            inv_z[k] = 1.0 / v.position[2];
        }
        (fixed, inv_z)
    }

    /// The pixels (x0, x1, y0, y1, inclusive) whose centres the corners `p` (fixed point) may
    /// cover, within the target; `None` when there are none.
    #[inline(always)]
    fn pixel_bounds(&self, p: &[(i64, i64); 3]) -> Option<(i64, i64, i64, i64)> {
        let min_x = p.iter().map(|v| v.0).min().unwrap_or(0);
        let max_x = p.iter().map(|v| v.0).max().unwrap_or(0);
        let min_y = p.iter().map(|v| v.1).min().unwrap_or(0);
        let max_y = p.iter().map(|v| v.1).max().unwrap_or(0);
        let half = (SUBPIXEL / 2.0) as i64;
        let step = SUBPIXEL as i64;
        let x0 = ((min_x - half + step - 1).div_euclid(step)).max(0);
        let x1 = ((max_x - half).div_euclid(step)).min(self.width - 1);
        let y0 = ((min_y - half + step - 1).div_euclid(step)).max(0);
        let y1 = ((max_y - half).div_euclid(step)).min(self.height - 1);
        (x0 <= x1 && y0 <= y1).then_some((x0, x1, y0, y1))
    }

    /// Scans one (clipped) triangle into the G-buffer.
    fn draw(&mut self, vertices: [ClipVertex; 3], instance: u16, triangle: u32) {
        let (fixed, inv_z) = self.project(&vertices);
        let mut order = [0usize, 1, 2];
        let mut area = edge(fixed[0], fixed[1], fixed[2]);
        if area == 0 {
            return;
        }
        if area < 0 {
            order = [0, 2, 1];
            area = -area;
        }
        let p = order.map(|k| fixed[k]);
        let iz = order.map(|k| inv_z[k]);
        let bary = order.map(|k| vertices[k].bary);

        let half = (SUBPIXEL / 2.0) as i64;
        let step = SUBPIXEL as i64;
        let Some((x0, x1, y0, y1)) = self.pixel_bounds(&p) else {
            return;
        };
        let rect = PixelRect {
            x0: x0 as usize,
            x1: x1 as usize,
            y0: y0 as usize,
            y1: y1 as usize,
        };
        self.touched = Some(self.touched.map_or(rect, |t| t.union(rect)));
        let Edges {
            bias,
            step_x,
            step_y,
            mut row,
        } = Edges::of(&p, (x0 * step + half, y0 * step + half));
        let inv_area = 1.0 / area as f32;
        let (min_inv_z, max_inv_z) = (1.0 / self.far, 1.0 / self.near);
        let width = self.width as usize;
        for y in y0..=y1 {
            let (start, end) = row_span(row, step_x, x0, x1);
            if start <= end {
                let base = y as usize * width;
                let offset = start - x0;
                // Perspective weights w_k / (area z_k) are affine along the row: exact at the
                // span start, then start + step * i (no accumulated error).
                let w = [0, 1, 2].map(|k| (row[k] + step_x[k] * offset - bias[k]) as f32);
                let scale = [0, 1, 2].map(|k| inv_area * iz[k]);
                let pz0 = [0, 1, 2].map(|k| w[k] * scale[k]);
                let dpz = [0, 1, 2].map(|k| step_x[k] as f32 * scale[k]);
                let sum0 = pz0[0] + pz0[1] + pz0[2];
                let dsum = dpz[0] + dpz[1] + dpz[2];
                let range = base + start as usize..=base + end as usize;
                let inv_depth = &mut self.inv_depth[range.clone()];
                let instances = &mut self.instance[range.clone()];
                let triangles = &mut self.triangle[range.clone()];
                let barys = &mut self.bary[range];
                let pixels = inv_depth
                    .iter_mut()
                    .zip(instances)
                    .zip(triangles)
                    .zip(barys);
                let mut t = -1.0f32;
                for (((d, inst), tri), out) in pixels {
                    t += 1.0; // exact: spans are far shorter than 2^24 pixels
                    let sum = sum0 + dsum * t;
                    if sum > *d && (min_inv_z..=max_inv_z).contains(&sum) {
                        *d = sum;
                        *inst = instance;
                        *tri = triangle;
                        let z = 1.0 / sum;
                        let q = [
                            (pz0[0] + dpz[0] * t) * z,
                            (pz0[1] + dpz[1] * t) * z,
                            (pz0[2] + dpz[2] * t) * z,
                        ];
                        let b1 = q[0] * bary[0][1] + q[1] * bary[1][1] + q[2] * bary[2][1];
                        let b2 = q[0] * bary[0][2] + q[1] * bary[1][2] + q[2] * bary[2][2];
                        *out = [b1, b2];
                    }
                }
            }
            for k in 0..3 {
                row[k] += step_y[k];
            }
        }
    }
}

impl Rasterizer {
    /// Visibility pass: fills the G-buffer for `camera`.
    fn visibility(&mut self, camera: &Camera, instances: &[Instance<'_>], lighting: &Lighting) {
        let pixels = (camera.width_px * camera.height_px) as usize;
        self.changed = Changed::Anywhere;
        self.inv_depth.clear();
        self.inv_depth.resize(pixels, 0.0);
        self.instance.clear();
        self.instance.resize(pixels, NO_INSTANCE);
        self.triangle.resize(pixels, 0);
        self.bary.resize(pixels, [0.0; 2]);
        self.camera_positions.clear();
        self.camera_normals.clear();
        self.vertex_colours.clear();
        self.vertex_offsets.clear();
        self.visibility_from(camera, instances, lighting, 0);
    }

    /// Moves `instances[start..]`'s vertices and normals into the camera frame and lights the
    /// per-vertex ones.
    fn transform_vertices(
        &mut self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        start: usize,
    ) {
        let camera_from_world = camera.world_from_camera.inverse();
        for instance in instances.iter().skip(start) {
            let pose = camera_from_world * instance.world_from_mesh;
            let rotation = pose.rotation.to_rotation_matrix();
            let r = rotation.matrix().map(|v| v as f32);
            let t = pose.translation.vector.map(|v| v as f32);
            self.vertex_offsets.push(self.camera_positions.len());
            for (p, n) in instance
                .mesh
                .positions
                .iter()
                .zip(instance.mesh.normals.iter())
            {
                let pv = r * Vector3::new(p[0], p[1], p[2]) + t;
                let nv = r * Vector3::new(n[0], n[1], n[2]);
                self.camera_positions.push(pv.into());
                self.camera_normals.push(nv.into());
            }
            let material = &instance.material;
            let first = self.vertex_offsets[self.vertex_offsets.len() - 1];
            self.vertex_colours
                .resize(self.camera_positions.len(), [0.0; 3]);
            if material.per_vertex && lighting.allow_per_vertex {
                for (i, colour) in self.vertex_colours[first..].iter_mut().enumerate() {
                    let shade = instance.mesh.shade.get(i).copied().unwrap_or(1.0);
                    *colour = light(
                        material,
                        self.camera_positions[first + i],
                        self.camera_normals[first + i],
                        shade,
                        lighting,
                    );
                }
            }
        }
    }

    /// Draws `instances[start..]` over a G-buffer that holds `instances[..start]` drawn in
    /// order (and their camera-space vertices): the same buffers as drawing them all. Returns
    /// a rectangle holding every pixel written (`None`: none).
    fn visibility_from(
        &mut self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        start: usize,
    ) -> Option<PixelRect> {
        self.transform_vertices(camera, instances, lighting, start);
        let mut target = Target {
            width: i64::from(camera.width_px),
            height: i64::from(camera.height_px),
            fx: camera.fx_px,
            fy: camera.fy_px,
            cx: camera.cx_px,
            cy: camera.cy_px,
            near: camera.near_m as f32,
            far: camera.far_m as f32,
            inv_depth: &mut self.inv_depth,
            instance: &mut self.instance,
            triangle: &mut self.triangle,
            bary: &mut self.bary,
            touched: None,
        };
        let identity = [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]];
        let mut polygon = Vec::with_capacity(4);
        for (instance_index, instance) in instances
            .iter()
            .enumerate()
            .take(usize::from(NO_INSTANCE))
            .skip(start)
        {
            let offset = self.vertex_offsets[instance_index];
            for (triangle_index, tri) in instance.mesh.triangles.iter().enumerate() {
                let v = tri.map(|i| self.camera_positions[offset + i as usize]);
                let (near, far) = (target.near, target.far);
                if v.iter().all(|p| p[2] < near) || v.iter().all(|p| p[2] > far) {
                    continue;
                }
                if instance.cull_back_faces
                    && dot(cross(sub(v[1], v[0]), sub(v[2], v[0])), v[0]) >= 0.0
                {
                    continue;
                }
                let corners = [0, 1, 2].map(|k| ClipVertex {
                    position: v[k],
                    bary: identity[k],
                });
                let id = instance_index as u16;
                if v.iter().all(|p| p[2] >= near) {
                    target.draw(corners, id, triangle_index as u32);
                } else {
                    clip_near(corners, near, &mut polygon);
                    for k in 1..polygon.len().saturating_sub(1) {
                        target.draw(
                            [polygon[0], polygon[k], polygon[k + 1]],
                            id,
                            triangle_index as u32,
                        );
                    }
                }
            }
        }
        target.touched
    }

    /// Renders RGB, depth and mask; RGB optionally from a supersampled pass.
    pub fn render(
        &mut self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        supersample: u32,
    ) -> Frame {
        let mut frame = Frame {
            width_px: camera.width_px,
            height_px: camera.height_px,
            rgb: Vec::new(),
            depth_m: Vec::new(),
            mask: Vec::new(),
        };
        if supersample > 1 {
            let big = camera.scaled(supersample);
            self.visibility(&big, instances, lighting);
            let linear = self.shade(&big, instances, lighting);
            frame.rgb = downsample(&linear, big.width_px as usize, supersample as usize);
        }
        self.visibility(camera, instances, lighting);
        if supersample <= 1 {
            frame.rgb = self.shade_srgb(camera, instances, lighting);
        }
        self.depth_and_mask(instances, &mut frame);
        frame
    }

    /// [`Rasterizer::render`] (without supersampling) of a scene whose first `statics`
    /// instances stand still from frame to frame (the tray, drape and organs in an episode):
    /// their layer (G-buffer and shaded pixels) is drawn once and kept, and each frame draws
    /// only the rest over it and shades only the pixels they cover. The pixels are the same
    /// bytes as [`Rasterizer::render`]'s: instances are drawn in list order either way, and a
    /// pixel showing a static surface shades the same (the light sits at the lens; nothing
    /// casts shadows). A layer is redrawn when the camera, the lighting or any static
    /// instance (mesh, pose, material, mask, culling) differs from the kept one's.
    pub fn render_over_static(
        &mut self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        statics: usize,
    ) -> Frame {
        let statics = statics.min(instances.len());
        if self
            .layer
            .as_ref()
            .is_none_or(|layer| !layer.key.describes(camera, lighting, &instances[..statics]))
        {
            let key = StaticKey::of(camera, lighting, &instances[..statics]);
            self.visibility(camera, &instances[..statics], lighting);
            let rgb = self.shade_srgb(camera, &instances[..statics], lighting);
            self.layer = Some(StaticLayer {
                key,
                inv_depth: self.inv_depth.clone(),
                instance: self.instance.clone(),
                triangle: self.triangle.clone(),
                bary: self.bary.clone(),
                vertices: self.camera_positions.len(),
                rgb,
            });
            self.changed = Changed::Nowhere;
        }
        let Some(layer) = self.layer.as_ref() else {
            return self.render(camera, instances, lighting, 1);
        };
        // Back to the layer: only where the last frame's moving instances drew.
        match self.changed {
            Changed::Anywhere => {
                self.inv_depth.clone_from(&layer.inv_depth);
                self.instance.clone_from(&layer.instance);
                self.triangle.clone_from(&layer.triangle);
                self.bary.clone_from(&layer.bary);
            }
            Changed::Within(rect) => {
                let width = camera.width_px as usize;
                for y in rect.y0..=rect.y1 {
                    let row = y * width + rect.x0..=y * width + rect.x1;
                    self.inv_depth[row.clone()].copy_from_slice(&layer.inv_depth[row.clone()]);
                    self.instance[row.clone()].copy_from_slice(&layer.instance[row.clone()]);
                    self.triangle[row.clone()].copy_from_slice(&layer.triangle[row.clone()]);
                    self.bary[row.clone()].copy_from_slice(&layer.bary[row]);
                }
            }
            Changed::Nowhere => {}
        }
        self.camera_positions.truncate(layer.vertices);
        self.camera_normals.truncate(layer.vertices);
        self.vertex_colours.truncate(layer.vertices);
        self.vertex_offsets.truncate(statics);
        let (mut rgb, depth_m, mask) = self.spare.pop().unwrap_or_default();
        rgb.clear();
        rgb.extend_from_slice(&layer.rgb);
        let touched = self.visibility_from(camera, instances, lighting, statics);
        self.changed = touched.map_or(Changed::Nowhere, Changed::Within);
        if let Some(rect) = touched {
            self.shade_srgb_into(camera, instances, lighting, statics, Some(rect), &mut rgb);
        }
        let mut frame = Frame {
            width_px: camera.width_px,
            height_px: camera.height_px,
            rgb,
            depth_m,
            mask,
        };
        self.depth_and_mask(instances, &mut frame);
        frame
    }

    /// Takes back a frame's buffers (their contents do not matter): a later
    /// [`Rasterizer::render_over_static`] frame is drawn into them instead of new ones.
    pub fn recycle(&mut self, rgb: Vec<u8>, depth_m: Vec<f32>, mask: Vec<u8>) {
        self.spare.push((rgb, depth_m, mask));
    }

    /// The frame's depth and mask from the G-buffer.
    fn depth_and_mask(&self, instances: &[Instance<'_>], frame: &mut Frame) {
        frame.depth_m.clear();
        frame.depth_m.extend(
            self.inv_depth
                .iter()
                .map(|d| if *d > 0.0 { 1.0 / d } else { 0.0 }),
        );
        frame.mask.clear();
        if self.skip_mask {
            return;
        }
        frame.mask.extend(self.instance.iter().map(|i| {
            if *i == NO_INSTANCE {
                0
            } else {
                instances[usize::from(*i)].mask_id
            }
        }));
    }

    /// Shading pass over the G-buffer: linear RGB per pixel.
    fn shade(
        &self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
    ) -> Vec<[f32; 3]> {
        let mut out = vec![lighting.background; (camera.width_px * camera.height_px) as usize];
        self.shade_each(camera, instances, lighting, 0, None, |index, colour| {
            out[index] = colour
        });
        out
    }

    /// Shading pass over the G-buffer straight to sRGB bytes.
    fn shade_srgb(
        &self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
    ) -> Vec<u8> {
        let lut = srgb_table();
        let background = lighting.background.map(|c| lut.lookup(c));
        let mut out: Vec<u8> = background.repeat((camera.width_px * camera.height_px) as usize);
        self.shade_srgb_into(camera, instances, lighting, 0, None, &mut out);
        out
    }

    /// Shades into `out` (sRGB) the pixels whose surface belongs to `instances[first..]`
    /// (`within`: only those inside it).
    fn shade_srgb_into(
        &self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        first: usize,
        within: Option<PixelRect>,
        out: &mut [u8],
    ) {
        let lut = srgb_table();
        self.shade_each(
            camera,
            instances,
            lighting,
            first,
            within,
            |index, colour| {
                out[index * 3..index * 3 + 3].copy_from_slice(&colour.map(|c| lut.lookup(c)));
            },
        );
    }

    /// Calls `emit(pixel index, linear RGB)` for every pixel that shows a surface of
    /// `instances[first..]` (`within`: every such pixel inside it).
    fn shade_each(
        &self,
        camera: &Camera,
        instances: &[Instance<'_>],
        lighting: &Lighting,
        first: usize,
        within: Option<PixelRect>,
        mut emit: impl FnMut(usize, [f32; 3]),
    ) {
        let (w, h) = (camera.width_px as usize, camera.height_px as usize);
        let (cx, cy) = (camera.cx_px as f32, camera.cy_px as f32);
        let corner = cx * cx + cy * cy;
        let vignette_x: Vec<f32> = (0..w)
            .map(|x| (x as f32 + 0.5 - cx).powi(2) / corner)
            .collect();
        let ray_x: Vec<f32> = (0..w)
            .map(|x| (x as f32 + 0.5 - cx) / camera.fx_px as f32)
            .collect();
        let rect = within.unwrap_or(PixelRect {
            x0: 0,
            x1: w.saturating_sub(1),
            y0: 0,
            y1: h.saturating_sub(1),
        });
        let columns = rect.x0..(rect.x1 + 1).min(w);
        for y in rect.y0..(rect.y1 + 1).min(h) {
            let vignette_y = (y as f32 + 0.5 - cy).powi(2) / corner;
            let row = y * w + columns.start..y * w + columns.end;
            let inv_depth_row = &self.inv_depth[row.clone()];
            let ray_y = (y as f32 + 0.5 - cy) / camera.fy_px as f32;
            let pixels = self.instance[row.clone()]
                .iter()
                .zip(&self.triangle[row.clone()])
                .zip(&self.bary[row])
                .zip(&vignette_x[columns.clone()]);
            // Neighbouring pixels mostly show the same triangle: its vertex data is fetched once
            // per run.
            let mut run_key = (NO_INSTANCE, u32::MAX);
            let mut run = TriangleData::default();
            for (i, (((&instance_index, &triangle), &[b1, b2]), &vx)) in pixels.enumerate() {
                if instance_index == NO_INSTANCE || usize::from(instance_index) < first {
                    continue;
                }
                let x = columns.start + i;
                let instance = &instances[usize::from(instance_index)];
                if run_key != (instance_index, triangle) {
                    run_key = (instance_index, triangle);
                    run = TriangleData::fetch(
                        instance,
                        triangle,
                        self,
                        self.vertex_offsets[usize::from(instance_index)],
                    );
                }
                let b = [1.0 - b1 - b2, b1, b2];
                let vignette = 1.0 - lighting.vignette * (vx + vignette_y);
                let material = &instance.material;
                if material.per_vertex && lighting.allow_per_vertex {
                    let weights = [b[0] * vignette, b[1] * vignette, b[2] * vignette];
                    emit(y * w + x, interpolate(&run.colours, weights));
                    continue;
                }
                // The surface point from the pixel's ray and depth; the normal from the vertices.
                let z = 1.0 / inv_depth_row[i];
                let position = [ray_x[x] * z, ray_y * z, z];
                let normal = interpolate(&run.normals, b);
                let mut pattern = b[0] * run.shade[0] + b[1] * run.shade[1] + b[2] * run.shade[2];
                if run.patterned {
                    pattern *= material.pattern_factor(interpolate(&run.local, b));
                }
                let colour = light(material, position, normal, pattern, lighting);
                emit(y * w + x, colour.map(|c| c * vignette));
            }
        }
    }
}

/// Barycentric interpolation of three vectors.
#[inline]
fn interpolate(v: &[[f32; 3]; 3], b: [f32; 3]) -> [f32; 3] {
    [
        b[0] * v[0][0] + b[1] * v[1][0] + b[2] * v[2][0],
        b[0] * v[0][1] + b[1] * v[1][1] + b[2] * v[2][1],
        b[0] * v[0][2] + b[1] * v[1][2] + b[2] * v[2][2],
    ]
}

/// The endoscope light reflected by a surface point (camera frame) with normal `normal`
/// (any length) and pattern factor `pattern`: linear RGB before the vignette.
#[inline]
fn light(
    material: &Material,
    position: [f32; 3],
    normal: [f32; 3],
    pattern: f32,
    lighting: &Lighting,
) -> [f32; 3] {
    let reference = lighting.reference_distance_m * lighting.reference_distance_m;
    let distance2 = dot(position, position).max(1e-12);
    let normal2 = dot(normal, normal).max(1e-20);
    // cos = n . (-p) / (|n| |p|), two-sided (a surface seen from behind is lit too).
    let cos = (dot(normal, position) / (distance2 * normal2).sqrt()).abs();
    let irradiance = (lighting.light_gain * reference / distance2).min(lighting.max_irradiance);
    let mut highlight = cos;
    for _ in 0..material.shininess_log2 {
        highlight *= highlight;
    }
    let diffuse = (lighting.ambient + irradiance * cos) * pattern;
    let specular = material.specular * irradiance * highlight;
    material.albedo.map(|a| a * diffuse + specular)
}

/// A triangle's vertex data as the shading pass needs it.
#[derive(Clone, Copy, Debug, Default)]
struct TriangleData {
    normals: [[f32; 3]; 3],
    shade: [f32; 3],
    local: [[f32; 3]; 3],
    colours: [[f32; 3]; 3],
    patterned: bool,
}

impl TriangleData {
    fn fetch(instance: &Instance<'_>, triangle: u32, vertices: &Rasterizer, offset: usize) -> Self {
        let camera_normals = &vertices.camera_normals;
        let mesh = instance.mesh;
        let tri = mesh.triangles[triangle as usize].map(|v| v as usize);
        TriangleData {
            normals: tri.map(|v| camera_normals[offset + v]),
            shade: if mesh.shade.is_empty() {
                [1.0; 3]
            } else {
                tri.map(|v| mesh.shade[v])
            },
            local: tri.map(|v| mesh.positions[v]),
            colours: tri.map(|v| vertices.vertex_colours[offset + v]),
            patterned: instance.material.pattern != Pattern::Solid,
        }
    }
}

/// Box-filters a linear image by `factor` and converts to sRGB bytes.
fn downsample(linear: &[[f32; 3]], width: usize, factor: usize) -> Vec<u8> {
    let small_w = width / factor;
    let small_h = linear.len() / width / factor;
    let norm = 1.0 / (factor * factor) as f32;
    let lut = srgb_table();
    let mut out = Vec::with_capacity(small_w * small_h * 3);
    for y in 0..small_h {
        for x in 0..small_w {
            let mut sum = [0f32; 3];
            for sy in 0..factor {
                for sx in 0..factor {
                    let c = linear[(y * factor + sy) * width + x * factor + sx];
                    for k in 0..3 {
                        sum[k] += c[k].min(1.0);
                    }
                }
            }
            out.extend(sum.map(|s| lut.lookup(s * norm)));
        }
    }
    out
}

/// The camera-frame point of a pixel centre at its rendered depth (None for background).
pub fn pixel_point(camera: &Camera, frame: &Frame, u: u32, v: u32) -> Option<Point3<f64>> {
    let z = *frame.depth_m.get((v * frame.width_px + u) as usize)?;
    (z > 0.0).then(|| camera.back_project(u, v, f64::from(z)))
}

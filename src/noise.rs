//! Seeded value noise shared by the procedural organ shapes (scene data, used by physics and
//! drawing alike) and the renderer's surface patterns.

/// A hash of a lattice point to [-1, 1].
#[inline]
pub(crate) fn lattice_hash(x: i32, y: i32, z: i32, seed: u32) -> f32 {
    let mut h = (x as u32).wrapping_mul(0x8da6_b343)
        ^ (y as u32).wrapping_mul(0xd816_3841)
        ^ (z as u32).wrapping_mul(0xcb1a_b31f)
        ^ seed.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 15;
    h = h.wrapping_mul(0x2c1b_3c6d);
    h ^= h >> 12;
    h = h.wrapping_mul(0x297a_2d39);
    h ^= h >> 15;
    (h & 0x00ff_ffff) as f32 / 8_388_607.5 - 1.0
}

/// `floor` without a libm call (the baseline x86-64 target has no rounding instruction).
#[inline]
pub(crate) fn floor_i32(x: f32) -> i32 {
    let i = x as i32;
    if (i as f32) > x { i - 1 } else { i }
}

/// Smooth 3-D value noise in [-1, 1] with unit lattice spacing, deterministic in `seed`.
pub fn value_noise3(p: [f32; 3], seed: u32) -> f32 {
    let [x, y, z] = p.map(floor_i32);
    let [fx, fy, fz] = [p[0] - x as f32, p[1] - y as f32, p[2] - z as f32];
    let smooth = |t: f32| t * t * (3.0 - 2.0 * t);
    let (sx, sy, sz) = (smooth(fx), smooth(fy), smooth(fz));
    let lerp = |a: f32, b: f32, t: f32| a + (b - a) * t;
    let h = |dx: i32, dy: i32, dz: i32| lattice_hash(x + dx, y + dy, z + dz, seed);
    let x00 = lerp(h(0, 0, 0), h(1, 0, 0), sx);
    let x10 = lerp(h(0, 1, 0), h(1, 1, 0), sx);
    let x01 = lerp(h(0, 0, 1), h(1, 0, 1), sx);
    let x11 = lerp(h(0, 1, 1), h(1, 1, 1), sx);
    lerp(lerp(x00, x10, sy), lerp(x01, x11, sy), sz)
}

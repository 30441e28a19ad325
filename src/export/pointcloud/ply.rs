//! A cloud as PLY (`binary_little_endian 1.0`, the standard `vertex` element with float x y z
//! and uchar red green blue, plus uchar `mask` when the cloud has mask ids): what plyfile,
//! Open3D and CloudCompare read. Only the cloud's real points are written, not its padding.

use crate::export::pointcloud::cloud::Cloud;

/// The PLY file of `cloud`.
pub fn encode_ply(cloud: &Cloud) -> Vec<u8> {
    let with_mask = !cloud.mask.is_empty();
    let mut header = format!(
        "ply\nformat binary_little_endian 1.0\ncomment surgvla point cloud, world frame, metres\n\
         element vertex {}\nproperty float x\nproperty float y\nproperty float z\n\
         property uchar red\nproperty uchar green\nproperty uchar blue\n",
        cloud.valid
    );
    if with_mask {
        header.push_str("property uchar mask\n");
    }
    header.push_str("end_header\n");
    let stride = 15 + usize::from(with_mask);
    let mut out = Vec::with_capacity(header.len() + cloud.valid * stride);
    out.extend_from_slice(header.as_bytes());
    for i in 0..cloud.valid {
        for v in cloud.xyz_m[i] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        out.extend_from_slice(&cloud.rgb[i]);
        if with_mask {
            out.push(cloud.mask[i]);
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_header_declares_what_the_body_holds() {
        let cloud = Cloud {
            xyz_m: vec![[1.0, 2.0, 3.0], [0.0; 3]],
            rgb: vec![[10, 20, 30], [0; 3]],
            mask: vec![5, 0],
            valid: 1,
        };
        let bytes = encode_ply(&cloud);
        let text = String::from_utf8_lossy(&bytes);
        let end = text.find("end_header\n").expect("header") + "end_header\n".len();
        assert!(text.starts_with("ply\nformat binary_little_endian 1.0\n"));
        assert!(text[..end].contains("element vertex 1\n"));
        assert!(text[..end].contains("property uchar mask\n"));
        let body = &bytes[end..];
        assert_eq!(body.len(), 16);
        assert_eq!(&body[..4], &1.0f32.to_le_bytes());
        assert_eq!(&body[12..], &[10, 20, 30, 5]);
    }
}

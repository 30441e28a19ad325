//! A cloud as PCD v0.7 (binary; `FIELDS x y z rgb`, rgb packed `0x00RRGGBB` in an unsigned
//! 32-bit field, plus `label` when the cloud has mask ids): what PCL and Open3D read. Only the
//! cloud's real points are written, not its padding.

use crate::export::pointcloud::cloud::Cloud;

/// The PCD file of `cloud`.
pub fn encode_pcd(cloud: &Cloud) -> Vec<u8> {
    let with_mask = !cloud.mask.is_empty();
    let (fields, size, kind, count) = if with_mask {
        ("x y z rgb label", "4 4 4 4 4", "F F F U U", "1 1 1 1 1")
    } else {
        ("x y z rgb", "4 4 4 4", "F F F U", "1 1 1 1")
    };
    let n = cloud.valid;
    let header = format!(
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\nFIELDS {fields}\nSIZE {size}\n\
         TYPE {kind}\nCOUNT {count}\nWIDTH {n}\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS {n}\n\
         DATA binary\n"
    );
    let stride = if with_mask { 20 } else { 16 };
    let mut out = Vec::with_capacity(header.len() + n * stride);
    out.extend_from_slice(header.as_bytes());
    for i in 0..n {
        for v in cloud.xyz_m[i] {
            out.extend_from_slice(&v.to_le_bytes());
        }
        let [r, g, b] = cloud.rgb[i];
        let packed = (u32::from(r) << 16) | (u32::from(g) << 8) | u32::from(b);
        out.extend_from_slice(&packed.to_le_bytes());
        if with_mask {
            out.extend_from_slice(&u32::from(cloud.mask[i]).to_le_bytes());
        }
    }
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn rgb_is_packed_and_padding_left_out() {
        let cloud = Cloud {
            xyz_m: vec![[0.5, 0.0, -1.0], [0.0; 3], [0.0; 3]],
            rgb: vec![[0x12, 0x34, 0x56], [0; 3], [0; 3]],
            mask: Vec::new(),
            valid: 1,
        };
        let bytes = encode_pcd(&cloud);
        let text = String::from_utf8_lossy(&bytes);
        let end = text.find("DATA binary\n").expect("header") + "DATA binary\n".len();
        assert!(text[..end].contains("FIELDS x y z rgb\n") && text[..end].contains("POINTS 1\n"));
        let body = &bytes[end..];
        assert_eq!(body.len(), 16);
        assert_eq!(&body[12..], &0x0012_3456u32.to_le_bytes());
    }
}

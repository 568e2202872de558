//! A small PLY writer for point clouds: `x y z` (double), `ray_id` (ushort), `miss` (double) and,
//! when every point has one, `sigma_x sigma_y sigma_z` (double). ASCII or binary little endian.
//! Files are written to a temporary file in the target directory and renamed, so a failure never
//! leaves a partial cloud behind.

use crate::io::atomic::write_atomic;
use crate::reconstruct::ReconstructedPoint;
use anyhow::Result;
use std::path::Path;

/// PLY body encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

/// The PLY header for `count` points, with the σ properties or not.
pub fn header(count: usize, with_sigma: bool, encoding: Encoding) -> String {
    let format = match encoding {
        Encoding::Ascii => "ascii",
        Encoding::BinaryLittleEndian => "binary_little_endian",
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment deltaz point cloud, mm\nelement vertex {count}\n\
         property double x\nproperty double y\nproperty double z\nproperty ushort ray_id\n\
         property double miss\n"
    );
    if with_sigma {
        out += "property double sigma_x\nproperty double sigma_y\nproperty double sigma_z\n";
    }
    out += "end_header\n";
    out
}

/// Appends one point's vertex (its σ only `with_sigma`).
pub fn push_point(
    bytes: &mut Vec<u8>,
    p: &ReconstructedPoint,
    with_sigma: bool,
    encoding: Encoding,
) {
    let sigma = p.sigma.filter(|_| with_sigma);
    match encoding {
        Encoding::Ascii => {
            let mut line = format!(
                "{} {} {} {} {}",
                p.point.x, p.point.y, p.point.z, p.id, p.miss
            );
            if let Some(s) = sigma {
                line += &format!(" {} {} {}", s.x, s.y, s.z);
            }
            line.push('\n');
            bytes.extend_from_slice(line.as_bytes());
        }
        Encoding::BinaryLittleEndian => {
            for v in p.point.iter() {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
            bytes.extend_from_slice(&p.id.to_le_bytes());
            bytes.extend_from_slice(&p.miss.to_le_bytes());
            for v in sigma.iter().flat_map(|s| s.iter()) {
                bytes.extend_from_slice(&v.to_le_bytes());
            }
        }
    }
}

/// The whole PLY file as bytes.
pub fn encode(points: &[ReconstructedPoint], encoding: Encoding) -> Vec<u8> {
    let with_sigma = !points.is_empty() && points.iter().all(|p| p.sigma.is_some());
    let mut bytes = header(points.len(), with_sigma, encoding).into_bytes();
    for p in points {
        push_point(&mut bytes, p, with_sigma, encoding);
    }
    bytes
}

/// Writes a point cloud as PLY (atomically).
pub fn write_ply(path: &Path, points: &[ReconstructedPoint], encoding: Encoding) -> Result<()> {
    Ok(write_atomic(path, &encode(points, encoding))?)
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::Vector3;

    fn point(sigma: bool) -> ReconstructedPoint {
        ReconstructedPoint {
            id: 203,
            point: Vector3::new(1.5, -2.0, 200.25),
            miss: 0.125,
            sigma: sigma.then(|| Vector3::new(0.5, 0.25, 2.0)),
        }
    }

    #[test]
    fn ascii_with_and_without_sigma() {
        let text = String::from_utf8(encode(&[point(true)], Encoding::Ascii)).unwrap();
        assert!(text.starts_with("ply\nformat ascii 1.0\n"));
        assert!(text.contains("element vertex 1\n") && text.contains("property double sigma_z\n"));
        assert!(
            text.ends_with("end_header\n1.5 -2 200.25 203 0.125 0.5 0.25 2\n"),
            "{text}"
        );
        let mixed =
            String::from_utf8(encode(&[point(true), point(false)], Encoding::Ascii)).unwrap();
        assert!(
            !mixed.contains("sigma") && mixed.ends_with("203 0.125\n1.5 -2 200.25 203 0.125\n")
        );
    }

    #[test]
    fn binary_bytes() {
        let bytes = encode(&[point(false)], Encoding::BinaryLittleEndian);
        let header_end = bytes
            .windows(11)
            .position(|w| w == b"end_header\n")
            .unwrap()
            + 11;
        let body = &bytes[header_end..];
        let mut want = Vec::new();
        for v in [1.5f64, -2.0, 200.25] {
            want.extend_from_slice(&v.to_le_bytes());
        }
        want.extend_from_slice(&[203, 0]);
        want.extend_from_slice(&0.125f64.to_le_bytes());
        assert_eq!(body, &want[..]);
        assert_eq!(body.len(), 8 * 3 + 2 + 8);
    }

    #[test]
    fn atomic_write_leaves_nothing_on_failure() {
        let dir = std::env::temp_dir().join(format!("deltaz-ply-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let ok = dir.join("cloud.ply");
        write_ply(&ok, &[point(true)], Encoding::Ascii).unwrap();
        assert!(std::fs::read_to_string(&ok).unwrap().starts_with("ply\n"));
        // The target is a directory: the rename fails, no temporary file stays.
        let blocked = dir.join("blocked.ply");
        std::fs::create_dir_all(blocked.join("inside")).unwrap();
        assert!(write_ply(&blocked, &[point(true)], Encoding::Ascii).is_err());
        let names: Vec<_> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(names.iter().all(|n| !n.contains(".tmp")), "{names:?}");
        std::fs::remove_dir_all(&dir).unwrap();
    }
}

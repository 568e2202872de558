//! A small PLY writer for point clouds: `x y z` (double), `ray_id` (ushort), `miss` (double) and,
//! when every point has one, `sigma_x sigma_y sigma_z` (double). ASCII or binary little endian.
//! Files are written to a temporary file in the target directory and renamed, so a failure never
//! leaves a partial cloud behind.

use super::{FileError, Result};
use deltaz_calib::reconstruct::ReconstructedPoint;
use nalgebra::Vector3;
use std::path::Path;

/// PLY body encoding.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Encoding {
    /// `format ascii 1.0`.
    Ascii,
    /// `format binary_little_endian 1.0`.
    BinaryLittleEndian,
}

/// What the header says about a cloud beyond its points: the frame, the calibration and, for
/// clouds of several images, each point's frame (image) index.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct CloudInfo {
    /// The coordinate frame, in words.
    pub frame: String,
    /// The fingerprint of the calibration (system.json) the points come from.
    pub fingerprint: Option<String>,
    /// Each point's frame index (written as the `frame` property when present).
    pub frames: Option<Vec<u32>>,
    /// The step the dots' centroids were quantised to on the way to the device (px), for
    /// clouds the device computed.
    pub centroid_step_px: Option<f64>,
}

/// Which properties every vertex of a cloud has.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Layout {
    /// ASCII or binary.
    pub encoding: Encoding,
    /// `sigma_x sigma_y sigma_z` after `miss`.
    pub sigma: bool,
    /// `frame` (uint) last.
    pub frame: bool,
}

/// The whole PLY file as bytes; header comments give units, frame and fingerprint.
pub fn encode_with(points: &[ReconstructedPoint], encoding: Encoding, info: &CloudInfo) -> Vec<u8> {
    let frames = info.frames.as_deref().filter(|f| f.len() == points.len());
    let layout = Layout {
        encoding,
        sigma: !points.is_empty() && points.iter().all(|p| p.sigma.is_some()),
        frame: frames.is_some(),
    };
    let mut bytes = header(points.len(), &layout, info).into_bytes();
    for (index, p) in points.iter().enumerate() {
        push_point(&mut bytes, p, frames.map(|f| f[index]), &layout);
    }
    bytes
}

/// The PLY header for `count` vertices of `layout`; comments give units, frame and fingerprint
/// (`info.frames` is not used: `layout.frame` says whether the property is there).
pub fn header(count: usize, layout: &Layout, info: &CloudInfo) -> String {
    let format = match layout.encoding {
        Encoding::Ascii => "ascii",
        Encoding::BinaryLittleEndian => "binary_little_endian",
    };
    let mut out = format!(
        "ply\nformat {format} 1.0\ncomment deltaz point cloud, mm\n\
         comment units: mm (coordinates, miss distance, standard deviations); ray_id = projector ray\n\
         comment frame: {}\n",
        info.frame
    );
    if let Some(fingerprint) = &info.fingerprint {
        out += &format!("comment calibration fingerprint: {fingerprint}\n");
    }
    if let Some(q) = info.centroid_step_px {
        out += &format!("comment centroid quantisation: {q} px\n");
    }
    if layout.frame {
        out += "comment frame property: index of the image in the observations, from 0\n";
    }
    out += &format!(
        "element vertex {count}\nproperty double x\nproperty double y\nproperty double z\n\
         property ushort ray_id\nproperty double miss\n"
    );
    if layout.sigma {
        out += "property double sigma_x\nproperty double sigma_y\nproperty double sigma_z\n";
    }
    if layout.frame {
        out += "property uint frame\n";
    }
    out += "end_header\n";
    out
}

/// Appends one vertex of `layout` (σ only when the layout has it; `frame` when it has one).
pub fn push_point(
    bytes: &mut Vec<u8>,
    p: &ReconstructedPoint,
    frame: Option<u32>,
    layout: &Layout,
) {
    let sigma = p.sigma.filter(|_| layout.sigma);
    let frame = frame.filter(|_| layout.frame);
    match layout.encoding {
        Encoding::Ascii => {
            let mut line = format!(
                "{} {} {} {} {}",
                p.point.x, p.point.y, p.point.z, p.id, p.miss
            );
            if let Some(s) = sigma {
                line += &format!(" {} {} {}", s.x, s.y, s.z);
            }
            if let Some(f) = frame {
                line += &format!(" {f}");
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
            if let Some(f) = frame {
                bytes.extend_from_slice(&f.to_le_bytes());
            }
        }
    }
}

/// A point cloud read back: its vertices and what its header says.
#[derive(Debug, Clone, PartialEq, Default)]
pub struct Cloud {
    /// The frame the header names (`comment frame: …`), if any.
    pub frame: Option<String>,
    /// The calibration's fingerprint the header names, if any.
    pub fingerprint: Option<String>,
    /// The device's centroid quantisation step the header names (px), if any.
    pub centroid_step_px: Option<f64>,
    /// The vertices, in the file's order.
    pub vertices: Vec<Vertex>,
}

/// One vertex: its point and the properties deltaz writes, where the file has them.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct Vertex {
    /// x, y, z.
    pub point: Vector3<f64>,
    /// `ray_id`.
    pub ray: Option<u16>,
    /// `frame`: the index of the point's image.
    pub frame: Option<u32>,
    /// `sigma_x`, `sigma_y`, `sigma_z`.
    pub sigma: Option<Vector3<f64>>,
}

/// Reads a PLY cloud: ASCII or binary little endian vertices of scalar properties (x, y, z and
/// any others; deltaz's `ray_id`, `frame` and `sigma_*` are kept), the vertex count checked
/// against the file's size before anything is allocated. Elements after the vertices (a mesh's
/// faces) are not read.
pub fn read_cloud(path: &Path) -> Result<Cloud> {
    let bytes = std::fs::read(path).map_err(|e| FileError::whole(path, e.to_string()))?;
    // The header's lines end in LF, or CR LF as Windows writes them.
    let (end, body) = [&b"end_header\n"[..], b"end_header\r\n"]
        .iter()
        .find_map(|tag| {
            let at = bytes.windows(tag.len()).position(|w| w == *tag)?;
            Some((at, &bytes[at + tag.len()..]))
        })
        .ok_or_else(|| FileError::whole(path, "not a PLY file: no `end_header` line"))?;
    let header = std::str::from_utf8(&bytes[..end])
        .map_err(|_| FileError::whole(path, "the PLY header is not text"))?;
    let mut cloud = Cloud::default();
    let mut ascii = None;
    let mut count = None;
    let mut properties: Vec<(String, &str)> = Vec::new();
    // Whether the header's lines are the vertex element's (not a later one's: a mesh's faces).
    let mut in_vertex = false;
    for (index, line) in header.lines().enumerate() {
        let at = |problem: String| FileError::at(path, index + 1, problem);
        let words: Vec<&str> = line.split_whitespace().collect();
        match words[..] {
            ["ply"] if index == 0 => {}
            _ if index == 0 => return Err(at("not a PLY file: no `ply` line".into())),
            ["format", "ascii", _] => ascii = Some(true),
            ["format", "binary_little_endian", _] => ascii = Some(false),
            ["format", other, _] => return Err(at(format!("format {other} is not supported"))),
            ["element", "vertex", n] if count.is_none() => {
                count = Some(
                    n.parse::<usize>()
                        .map_err(|_| at(format!("vertex count {n:?}")))?,
                );
                in_vertex = true;
            }
            ["element", ..] if count.is_some() => in_vertex = false,
            ["element", ..] => return Err(at("the `vertex` element must come first".into())),
            ["property", ..] if !in_vertex => {}
            ["property", "list", ..] => return Err(at("list properties are not read".into())),
            ["property", kind, name] => {
                scalar_size(kind).ok_or_else(|| at(format!("property type {kind:?}")))?;
                properties.push((name.to_owned(), kind));
            }
            ["comment", ..] => {
                let text = line["comment".len()..].trim();
                if let Some(frame) = text.strip_prefix("frame: ") {
                    cloud.frame = Some(frame.to_owned());
                }
                if let Some(f) = text.strip_prefix("calibration fingerprint: ") {
                    cloud.fingerprint = Some(f.to_owned());
                }
                if let Some(q) = text.strip_prefix("centroid quantisation: ") {
                    let q = q.trim_end_matches(" px").parse::<f64>();
                    let q = q.ok().filter(|q| q.is_finite() && *q > 0.0);
                    cloud.centroid_step_px =
                        Some(q.ok_or_else(|| at(format!("centroid quantisation {text:?}")))?);
                }
            }
            ["obj_info", ..] | [] => {}
            _ => return Err(at(format!("unexpected header line {line:?}"))),
        }
    }
    let (Some(ascii), Some(count)) = (ascii, count) else {
        return Err(FileError::whole(
            path,
            "the PLY header lacks `format` or `element vertex`",
        ));
    };
    let column = |name: &str| properties.iter().position(|(n, _)| n == name);
    let (Some(x), Some(y), Some(z)) = (column("x"), column("y"), column("z")) else {
        return Err(FileError::whole(path, "the PLY vertices lack x, y or z"));
    };
    let (ray, frame) = (column("ray_id"), column("frame"));
    let sigma = match (column("sigma_x"), column("sigma_y"), column("sigma_z")) {
        (Some(a), Some(b), Some(c)) => Some([a, b, c]),
        _ => None,
    };
    let row_size: usize = properties.iter().filter_map(|(_, k)| scalar_size(k)).sum();
    let least = if ascii {
        2 * properties.len()
    } else {
        row_size
    };
    if count.saturating_mul(least) > body.len() {
        return Err(FileError::whole(
            path,
            format!("{count} vertices announced, the file holds fewer"),
        ));
    }
    let mut ascii_lines = std::str::from_utf8(body)
        .ok()
        .filter(|_| ascii)
        .map(|text| text.lines());
    cloud.vertices.reserve(count);
    for vertex in 0..count {
        let problem = |p: &str| FileError::whole(path, format!("vertex {vertex}: {p}"));
        let values: Vec<f64> = match ascii_lines.as_mut() {
            Some(lines) => {
                let line = lines.next().ok_or_else(|| problem("missing"))?;
                let values: std::result::Result<Vec<f64>, _> =
                    line.split_whitespace().map(str::parse).collect();
                values.map_err(|_| problem("not numbers"))?
            }
            None if ascii => return Err(problem("the ASCII body is not text")),
            None => {
                let mut offset = vertex * row_size;
                properties
                    .iter()
                    .map(|(_, kind)| {
                        let value = binary_scalar(kind, &body[offset..]);
                        offset += scalar_size(kind).unwrap_or(0);
                        value
                    })
                    .collect()
            }
        };
        if values.len() != properties.len() {
            return Err(problem("wrong count of values"));
        }
        if values.iter().any(|v| !v.is_finite()) {
            return Err(problem(
                "a value not finite (some scanners write NaN for a point not measured: leave \
                 such points out of the file)",
            ));
        }
        let whole = |v: f64, max: f64| (v >= 0.0 && v <= max && v.fract() == 0.0).then_some(v);
        let ray = match ray {
            Some(r) => Some(whole(values[r], 65535.0).ok_or_else(|| problem("ray_id"))? as u16),
            None => None,
        };
        let frame = match frame {
            Some(f) => Some(whole(values[f], 4e9).ok_or_else(|| problem("frame"))? as u32),
            None => None,
        };
        cloud.vertices.push(Vertex {
            point: Vector3::new(values[x], values[y], values[z]),
            ray,
            frame,
            sigma: sigma.map(|[a, b, c]| Vector3::new(values[a], values[b], values[c])),
        });
    }
    Ok(cloud)
}

/// The labelled points of a PLY cloud for `compare`: the label is the `ray_id` (with a `frame`
/// property `frame:ray_id`, when the cloud holds several frames), or the vertex index without
/// one.
pub fn read_points(path: &Path) -> Result<Vec<(String, Vector3<f64>)>> {
    let vertices = read_cloud(path)?.vertices;
    // The frame joins the label only when the cloud holds several frames.
    let several = vertices.windows(2).any(|w| w[0].frame != w[1].frame);
    Ok(vertices
        .iter()
        .enumerate()
        .map(|(k, v)| {
            let label = v.ray.map_or(k.to_string(), |r| r.to_string());
            match v.frame.filter(|_| several) {
                Some(f) => (format!("{f}:{label}"), v.point),
                None => (label, v.point),
            }
        })
        .collect())
}

/// Bytes of a PLY scalar type.
fn scalar_size(kind: &str) -> Option<usize> {
    match kind {
        "char" | "uchar" | "int8" | "uint8" => Some(1),
        "short" | "ushort" | "int16" | "uint16" => Some(2),
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => Some(4),
        "double" | "float64" => Some(8),
        _ => None,
    }
}

/// A little-endian scalar at the start of `bytes` (long enough: checked against the count).
fn binary_scalar(kind: &str, bytes: &[u8]) -> f64 {
    let take = |n: usize| -> [u8; 8] {
        let mut a = [0; 8];
        a[..n].copy_from_slice(&bytes[..n]);
        a
    };
    match kind {
        "char" | "int8" => f64::from(bytes[0] as i8),
        "uchar" | "uint8" => f64::from(bytes[0]),
        "short" | "int16" => f64::from(i16::from_le_bytes([bytes[0], bytes[1]])),
        "ushort" | "uint16" => f64::from(u16::from_le_bytes([bytes[0], bytes[1]])),
        "int" | "int32" => f64::from(i32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]])),
        "uint" | "uint32" => {
            f64::from(u32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
        }
        "float" | "float32" => {
            f64::from(f32::from_le_bytes([bytes[0], bytes[1], bytes[2], bytes[3]]))
        }
        _ => f64::from_le_bytes(take(8)),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    const FRAME: &str = "the camera system";

    fn encode(points: &[ReconstructedPoint], encoding: Encoding) -> Vec<u8> {
        let info = CloudInfo {
            frame: FRAME.to_owned(),
            ..CloudInfo::default()
        };
        encode_with(points, encoding, &info)
    }

    fn write_ply(path: &Path, points: &[ReconstructedPoint], encoding: Encoding) -> Result<()> {
        crate::io::atomic::write_atomic(path, &encode(points, encoding))
    }

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

    /// Header comments, the `frame` property, and both encodings read back with their labels.
    #[test]
    fn frames_and_header_read_back() {
        let info = CloudInfo {
            frame: FRAME.to_owned(),
            fingerprint: Some("f0ce4228bb54066c".into()),
            frames: Some(vec![0, 3]),
            centroid_step_px: Some(0.015625),
        };
        let mut second = point(false);
        second.point.x = 7.0;
        let dir = tempfile::tempdir().unwrap();
        for encoding in [Encoding::Ascii, Encoding::BinaryLittleEndian] {
            let bytes = encode_with(&[point(false), second], encoding, &info);
            let text = String::from_utf8_lossy(&bytes);
            assert!(text.contains("comment calibration fingerprint: f0ce4228bb54066c\n"));
            assert!(
                text.contains("comment frame: the camera system\n")
                    && text.contains("property uint frame\n")
            );
            let path = dir.path().join("c.ply");
            std::fs::write(&path, &bytes).unwrap();
            let back = read_points(&path).unwrap();
            assert_eq!(
                back[0],
                ("0:203".to_owned(), Vector3::new(1.5, -2.0, 200.25))
            );
            assert_eq!(back[1].0, "3:203");
            assert_eq!(back[1].1.x, 7.0);
            let cloud = read_cloud(&path).unwrap();
            assert_eq!(cloud.frame.as_deref(), Some(FRAME));
            assert_eq!(cloud.fingerprint.as_deref(), Some("f0ce4228bb54066c"));
            assert_eq!(cloud.centroid_step_px, Some(0.015625));
            assert_eq!(
                cloud
                    .vertices
                    .iter()
                    .map(|v| (v.ray, v.frame))
                    .collect::<Vec<_>>(),
                [(Some(203), Some(0)), (Some(203), Some(3))]
            );
            std::fs::write(&path, &bytes[..bytes.len() - 3]).unwrap();
            let e = read_points(&path).unwrap_err().to_string();
            assert!(e.contains("c.ply") && e.contains("vert"), "{e}");
        }
    }

    /// A mesh's faces after its vertices are not read (its lines may end in CR LF); an element
    /// before them is refused.
    #[test]
    fn a_mesh_reads_its_vertices() {
        let dir = tempfile::tempdir().unwrap();
        let path = dir.path().join("m.ply");
        let mut bytes =
            b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\n\
            property float y\nproperty float z\nelement face 1\nproperty list uchar int \
            vertex_indices\nend_header\n"
                .to_vec();
        for v in [1.5f32, -2.0, -900.25] {
            bytes.extend_from_slice(&v.to_le_bytes());
        }
        bytes.extend_from_slice(&[3, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0, 0]);
        std::fs::write(&path, &bytes).unwrap();
        let cloud = read_cloud(&path).unwrap();
        let points: Vec<_> = cloud.vertices.iter().map(|v| (v.point, v.ray)).collect();
        assert_eq!(points, [(Vector3::new(1.5, -2.0, -900.25), None)]);
        // As Windows writes text: each line ending in CR LF.
        let text = "ply\r\nformat ascii 1.0\r\nelement vertex 1\r\nproperty float x\r\n\
                    property float y\r\nproperty float z\r\nend_header\r\n1.5 -2 -900.25\r\n";
        std::fs::write(&path, text).unwrap();
        let cloud = read_cloud(&path).unwrap();
        assert_eq!(cloud.vertices[0].point, Vector3::new(1.5, -2.0, -900.25));
        let text =
            "ply\nformat ascii 1.0\nelement face 0\nproperty list uchar int vertex_indices\n\
                    element vertex 1\nproperty float x\nend_header\n1\n";
        std::fs::write(&path, text).unwrap();
        let e = read_cloud(&path).unwrap_err().to_string();
        assert!(e.contains("m.ply") && e.contains("must come first"), "{e}");
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

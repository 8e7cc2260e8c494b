//! The node's map from a file (`node.map_path`): PLY (ASCII, binary little/big endian; the
//! `vertex` element's `x`, `y`, `z`) or PCD (ASCII, binary, binary_compressed; the `x`, `y`,
//! `z` fields), read with ply-rs-bw and pcd-rs. Points with a non-finite coordinate (the NaN
//! holes of organized clouds) are left out and counted.

use std::path::{Path, PathBuf};

use nalgebra::Point3;

use crate::frame::MapCloud;

/// Why a map file could not be used.
#[derive(Debug, thiserror::Error)]
pub enum MapFileError {
    #[error("map file {path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("map file {path}: unknown extension (expected .ply or .pcd)")]
    UnknownFormat { path: PathBuf },
    #[error("map file {path}: not a readable {format} file: {reason}")]
    Parse { path: PathBuf, format: &'static str, reason: String },
    #[error("map file {path}: no {what} (fields/properties found: {found})")]
    MissingCoordinates { path: PathBuf, what: &'static str, found: String },
    #[error("map file {path}: {finite} finite points of {total}: nothing to localize against")]
    NoPoints { path: PathBuf, finite: usize, total: usize },
}

/// A loaded map and what was left out of it.
#[derive(Debug)]
pub struct LoadedMap {
    pub map: MapCloud,
    /// Points with a non-finite coordinate, left out.
    pub non_finite: usize,
}

/// Reads the map in `path` (format by extension), in frame `frame_id`.
pub fn load(path: &Path, frame_id: &str) -> Result<LoadedMap, MapFileError> {
    let ext = path.extension().and_then(|e| e.to_str()).map(str::to_ascii_lowercase);
    let coords = match ext.as_deref() {
        Some("ply") => read_ply(path)?,
        Some("pcd") => read_pcd(path)?,
        _ => return Err(MapFileError::UnknownFormat { path: path.into() }),
    };
    let total = coords.len();
    let points: Vec<Point3<f32>> = coords
        .into_iter()
        .filter(|c| c.iter().all(|v| v.is_finite()))
        .map(|[x, y, z]| Point3::new(x as f32, y as f32, z as f32))
        .filter(|p| p.coords.iter().all(|v| v.is_finite()))
        .collect();
    if points.is_empty() {
        return Err(MapFileError::NoPoints { path: path.into(), finite: 0, total });
    }
    let non_finite = total - points.len();
    Ok(LoadedMap { map: MapCloud { frame_id: frame_id.to_string(), points }, non_finite })
}

/// A PLY vertex as read: its x, y, z (of any scalar type) and which of them the file gave. Only
/// these are kept (a generic element holds a map of every property: ~2 GB for 5 M vertices).
#[derive(Default)]
struct PlyVertex {
    xyz: [f64; 3],
    seen: u8,
}

impl ply_rs_bw::ply::PropertyAccess for PlyVertex {
    fn new() -> Self {
        Self::default()
    }

    fn set_property(&mut self, name: &str, property: ply_rs_bw::ply::Property) {
        use ply_rs_bw::ply::Property;
        let axis = match name {
            "x" => 0,
            "y" => 1,
            "z" => 2,
            _ => return,
        };
        let value = match property {
            Property::Char(v) => f64::from(v),
            Property::UChar(v) => f64::from(v),
            Property::Short(v) => f64::from(v),
            Property::UShort(v) => f64::from(v),
            Property::Int(v) => f64::from(v),
            Property::UInt(v) => f64::from(v),
            Property::Float(v) => f64::from(v),
            Property::Double(v) => v,
            // A list is no coordinate: the vertex stays without it (an error below).
            _ => return,
        };
        self.xyz[axis] = value;
        self.seen |= 1 << axis;
    }
}

fn read_ply(path: &Path) -> Result<Vec<[f64; 3]>, MapFileError> {
    use ply_rs_bw::parser::Parser;
    use ply_rs_bw::ply::DefaultElement;
    let file = std::fs::File::open(path).map_err(|source| MapFileError::Io { path: path.into(), source })?;
    let mut reader = std::io::BufReader::new(file);
    let parse = |e: std::io::Error| MapFileError::Parse { path: path.into(), format: "PLY", reason: e.to_string() };
    let missing = |found: String| MapFileError::MissingCoordinates { path: path.into(), what: "vertex x, y, z", found };
    let vertices = Parser::<PlyVertex>::new();
    let header = vertices.read_header(&mut reader).map_err(parse)?;
    for (name, element) in &header.elements {
        if name == "vertex" {
            let read = vertices.read_payload_for_element(&mut reader, element, &header).map_err(parse)?;
            let found = || element.properties.keys().cloned().collect::<Vec<_>>().join(", ");
            return read.into_iter().map(|v| if v.seen == 0b111 { Ok(v.xyz) } else { Err(missing(found())) }).collect();
        }
        // An element before the vertices (rare) is read past.
        Parser::<DefaultElement>::new().read_payload_for_element(&mut reader, element, &header).map_err(parse)?;
    }
    Err(missing(header.elements.keys().cloned().collect::<Vec<_>>().join(", ")))
}

fn read_pcd(path: &Path) -> Result<Vec<[f64; 3]>, MapFileError> {
    use pcd_rs::Field;
    let parse = |e: pcd_rs::Error| MapFileError::Parse { path: path.into(), format: "PCD", reason: e.to_string() };
    let reader = pcd_rs::DynReader::open(path).map_err(parse)?;
    let fields: Vec<String> = reader.meta().field_defs.fields.iter().map(|f| f.name.clone()).collect();
    let index = |name: &str| fields.iter().position(|f| f == name);
    let (Some(ix), Some(iy), Some(iz)) = (index("x"), index("y"), index("z")) else {
        return Err(MapFileError::MissingCoordinates {
            path: path.into(),
            what: "fields x, y, z",
            found: fields.join(", "),
        });
    };
    let scalar = |f: Option<&Field>| -> Option<f64> {
        Some(match f? {
            Field::I8(v) => f64::from(*v.first()?),
            Field::I16(v) => f64::from(*v.first()?),
            Field::I32(v) => f64::from(*v.first()?),
            Field::I64(v) => *v.first()? as f64,
            Field::U8(v) => f64::from(*v.first()?),
            Field::U16(v) => f64::from(*v.first()?),
            Field::U32(v) => f64::from(*v.first()?),
            Field::U64(v) => *v.first()? as f64,
            Field::F32(v) => f64::from(*v.first()?),
            Field::F64(v) => *v.first()?,
        })
    };
    let mut out = Vec::new();
    for record in reader {
        let record = record.map_err(parse)?;
        let r = &record.0;
        match (scalar(r.get(ix)), scalar(r.get(iy)), scalar(r.get(iz))) {
            (Some(x), Some(y), Some(z)) => out.push([x, y, z]),
            _ => {
                return Err(MapFileError::MissingCoordinates {
                    path: path.into(),
                    what: "values of x, y, z",
                    found: fields.join(", "),
                })
            }
        }
    }
    Ok(out)
}

#[cfg(test)]
mod tests {
    use super::*;

    const POINTS: [[f32; 3]; 3] = [[1.0, 2.0, 3.0], [-0.5, 0.25, 4.0], [f32::NAN, 0.0, 1.0]];

    /// (ASCII PLY has no NaN: the grammar takes numbers only.)
    fn ply_ascii() -> Vec<u8> {
        let mut s = String::from(
            "ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nproperty float y\nproperty float z\n\
             property uchar red\nend_header\n",
        );
        for p in &POINTS[..2] {
            s += &format!("{} {} {} 7\n", p[0], p[1], p[2]);
        }
        s.into_bytes()
    }

    fn ply_binary() -> Vec<u8> {
        let mut b = b"ply\nformat binary_little_endian 1.0\ncomment made by hand\nelement vertex 3\n\
                      property double x\nproperty double y\nproperty double z\nend_header\n"
            .to_vec();
        for p in POINTS {
            p.iter().for_each(|v| b.extend(f64::from(*v).to_le_bytes()));
        }
        b
    }

    fn pcd_header(data: &str) -> String {
        format!(
            "# .PCD v0.7\nVERSION 0.7\nFIELDS intensity x y z\nSIZE 4 4 4 4\nTYPE F F F F\nCOUNT 1 1 1 1\n\
             WIDTH 3\nHEIGHT 1\nVIEWPOINT 0 0 0 1 0 0 0\nPOINTS 3\nDATA {data}\n"
        )
    }

    fn pcd_ascii() -> Vec<u8> {
        let mut s = pcd_header("ascii");
        for p in POINTS {
            s += &format!("9 {} {} {}\n", p[0], p[1], p[2]).replace("NaN", "nan");
        }
        s.into_bytes()
    }

    fn pcd_binary() -> Vec<u8> {
        let mut b = pcd_header("binary").into_bytes();
        for p in POINTS {
            b.extend(9f32.to_le_bytes());
            p.iter().for_each(|v| b.extend(v.to_le_bytes()));
        }
        b
    }

    #[test]
    fn reads_ply_and_pcd_ascii_and_binary() {
        let tmp = tempfile::tempdir().unwrap();
        for (name, bytes, non_finite) in [
            ("a.ply", ply_ascii(), 0),
            ("b.PLY", ply_binary(), 1),
            ("c.pcd", pcd_ascii(), 1),
            ("d.pcd", pcd_binary(), 1),
        ] {
            let path = tmp.path().join(name);
            std::fs::write(&path, bytes).unwrap();
            let loaded = load(&path, "map").unwrap_or_else(|e| panic!("{name}: {e}"));
            assert_eq!(loaded.map.frame_id, "map");
            assert_eq!(loaded.non_finite, non_finite, "{name}");
            let got: Vec<[f32; 3]> = loaded.map.points.iter().map(|p| [p.x, p.y, p.z]).collect();
            assert_eq!(got, POINTS[..2].to_vec(), "{name}");
        }
    }

    #[test]
    fn ply_vertices_after_another_element_are_found() {
        let tmp = tempfile::tempdir().unwrap();
        let p = tmp.path().join("first.ply");
        let text = "ply\nformat ascii 1.0\nelement camera 1\nproperty uchar id\nelement vertex 2\nproperty double z\n\
                    property float x\nproperty float y\nproperty uchar red\nend_header\n7\n3 1 2 255\n6 4 5 0\n";
        std::fs::write(&p, text).unwrap();
        let loaded = load(&p, "map").unwrap();
        let got: Vec<[f32; 3]> = loaded.map.points.iter().map(|p| [p.x, p.y, p.z]).collect();
        assert_eq!(got, [[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]]);
    }

    #[test]
    fn bad_files_are_named_errors() {
        let tmp = tempfile::tempdir().unwrap();
        let write = |name: &str, bytes: &[u8]| {
            let p = tmp.path().join(name);
            std::fs::write(&p, bytes).unwrap();
            p
        };
        let e = load(&write("m.xyz", b"1 2 3\n"), "map").unwrap_err();
        assert!(matches!(e, MapFileError::UnknownFormat { .. }), "{e}");
        let e = load(&write("t.ply", b"ply\nformat ascii 1.0\nelement vertex 2\nproperty float x\nend"), "map")
            .unwrap_err();
        assert!(matches!(e, MapFileError::Parse { .. }), "{e}");
        let no_z = b"ply\nformat ascii 1.0\nelement vertex 1\nproperty float x\nproperty float y\nend_header\n1 2\n";
        let e = load(&write("noz.ply", no_z), "map").unwrap_err();
        assert!(matches!(e, MapFileError::MissingCoordinates { .. }), "{e}");
        let e = load(&tmp.path().join("absent.pcd"), "map").unwrap_err();
        assert!(e.to_string().contains("absent.pcd"), "{e}");
    }
}

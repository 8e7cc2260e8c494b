//! Minimal writer of NumPy `.npy` files (format 1.0, little-endian, C order), for training
//! samples that Python reads with `numpy.load`.

use std::io::Write;
use std::path::Path;

/// An element type numpy knows.
pub trait NpyElement: Copy {
    const DESCR: &'static str;
    fn write_le(self, out: &mut Vec<u8>);
    fn read_le(bytes: &[u8]) -> Self;
}

impl NpyElement for f32 {
    const DESCR: &'static str = "<f4";
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn read_le(b: &[u8]) -> Self {
        f32::from_le_bytes([b[0], b[1], b[2], b[3]])
    }
}

impl NpyElement for i64 {
    const DESCR: &'static str = "<i8";
    fn write_le(self, out: &mut Vec<u8>) {
        out.extend_from_slice(&self.to_le_bytes());
    }
    fn read_le(b: &[u8]) -> Self {
        i64::from_le_bytes([b[0], b[1], b[2], b[3], b[4], b[5], b[6], b[7]])
    }
}

/// The bytes of an `.npy` file holding `data` with `shape` (product of shape = data length).
pub fn encode<T: NpyElement>(data: &[T], shape: &[usize]) -> Vec<u8> {
    debug_assert_eq!(shape.iter().product::<usize>(), data.len());
    let dims: Vec<String> = shape.iter().map(|d| d.to_string()).collect();
    let shape_text = match dims.len() {
        1 => format!("({},)", dims[0]),
        _ => format!("({})", dims.join(", ")),
    };
    let mut header = format!("{{'descr': '{}', 'fortran_order': False, 'shape': {}, }}", T::DESCR, shape_text);
    // Magic (6) + version (2) + length (2) + header + '\n' is a multiple of 64.
    let unpadded = 10 + header.len() + 1;
    header.push_str(&" ".repeat((64 - unpadded % 64) % 64));
    header.push('\n');
    let mut out = Vec::with_capacity(10 + header.len() + data.len() * 8);
    out.extend_from_slice(b"\x93NUMPY\x01\x00");
    out.extend_from_slice(&(header.len() as u16).to_le_bytes());
    out.extend_from_slice(header.as_bytes());
    for &v in data {
        v.write_le(&mut out);
    }
    out
}

pub fn write<T: NpyElement>(path: &Path, data: &[T], shape: &[usize]) -> std::io::Result<()> {
    std::fs::File::create(path)?.write_all(&encode(data, shape))
}

/// Reads an `.npy` file of `T` (format 1.x/2.x, little-endian, C order): (data, shape).
pub fn read<T: NpyElement>(path: &Path) -> std::io::Result<(Vec<T>, Vec<usize>)> {
    let bytes = std::fs::read(path)?;
    let bad = |why: &str| std::io::Error::new(std::io::ErrorKind::InvalidData, format!("{}: {why}", path.display()));
    if bytes.len() < 10 || &bytes[..6] != b"\x93NUMPY" {
        return Err(bad("not an .npy file"));
    }
    let (len, start) = match bytes[6] {
        1 => (u16::from_le_bytes([bytes[8], bytes[9]]) as usize, 10),
        _ if bytes.len() >= 12 => (u32::from_le_bytes([bytes[8], bytes[9], bytes[10], bytes[11]]) as usize, 12),
        _ => return Err(bad("truncated header")),
    };
    let header =
        bytes.get(start..start + len).and_then(|h| std::str::from_utf8(h).ok()).ok_or_else(|| bad("bad header"))?;
    if !header.contains(&format!("'descr': '{}'", T::DESCR)) || header.contains("'fortran_order': True") {
        return Err(bad(&format!("expected C-order {} data, header {header}", T::DESCR)));
    }
    let shape_text =
        header.split("'shape': (").nth(1).and_then(|r| r.split(')').next()).ok_or_else(|| bad("no shape"))?;
    let shape: Vec<usize> = shape_text
        .split(',')
        .map(str::trim)
        .filter(|d| !d.is_empty())
        .map(|d| d.parse().map_err(|_| bad("bad shape")))
        .collect::<Result<_, _>>()?;
    let body = &bytes[start + len..];
    let size = std::mem::size_of::<T>();
    if body.len() != shape.iter().product::<usize>() * size {
        return Err(bad("data size does not match the shape"));
    }
    Ok((body.chunks_exact(size).map(T::read_le).collect(), shape))
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn header_is_aligned_and_describes_the_array() {
        let bytes = encode(&[1.0f32, 2.0, 3.0, 4.0, 5.0, 6.0], &[2, 3]);
        let header_len = u16::from_le_bytes([bytes[8], bytes[9]]) as usize;
        assert_eq!((10 + header_len) % 64, 0);
        let header = std::str::from_utf8(&bytes[10..10 + header_len]).unwrap();
        assert!(header.contains("'descr': '<f4'") && header.contains("'shape': (2, 3)"), "{header}");
        assert_eq!(bytes.len(), 10 + header_len + 24);
        assert_eq!(&bytes[10 + header_len..10 + header_len + 4], &1.0f32.to_le_bytes());
        let one = encode(&[7i64], &[1]);
        assert!(String::from_utf8_lossy(&one).contains("'descr': '<i8', 'fortran_order': False, 'shape': (1,)"));
        assert_eq!(&one[one.len() - 8..], &7i64.to_le_bytes());
    }

    #[test]
    fn read_inverts_write() {
        let dir = tempfile::tempdir().unwrap();
        let p = dir.path().join("a.npy");
        write(&p, &[1.5f32, -2.0, 3.25, 4.0], &[2, 2]).unwrap();
        assert_eq!(read::<f32>(&p).unwrap(), (vec![1.5, -2.0, 3.25, 4.0], vec![2, 2]));
        assert!(read::<i64>(&p).is_err());
    }
}

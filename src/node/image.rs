//! Camera images of the node: `sensor_msgs/Image` (`rgb8`, `bgr8`, `mono8`, `rgba8`, `bgra8`)
//! or `sensor_msgs/CompressedImage` (JPEG/PNG), and the debug image (kept correspondences
//! green, rejected red) drawn on it.
//!
//! Every image is held to `limits.max_image_side` and `limits.max_image_pixels` before a pixel
//! is decoded or copied (#38: 200 KB PNGs of 8192×8192 made the node hold 1.9–2.4 GB). A raw
//! image is converted to RGB in its reader thread ([`CameraImage::Raw`]); a compressed one
//! only has its header read there and travels in the frame as it came
//! ([`CameraImage::Compressed`], ~200 KB rather than ~200 MB decoded while it waits in the
//! queue), decoded when its debug image is drawn ([`from_encoded`]).

use std::collections::HashSet;

use image::{Rgb, RgbImage};

use crate::frame::{CameraImage, Correspondence, EncodedImage, Stamp};
use crate::limits::{check_image_size, InputLimits};
use crate::msgs::{CompressedImage, Header, Image};

/// Kept correspondences are drawn in this colour …
pub const KEPT: [u8; 3] = [0, 255, 0];
/// … rejected ones in this one.
pub const REJECTED: [u8; 3] = [255, 0, 0];
/// Half the side of the filled square drawn at each correspondence (5×5 pixels).
const HALF: i64 = 2;

/// Bytes per pixel and channel order of the raw encodings the node accepts:
/// (channels, index of R, G, B in a pixel).
fn layout(encoding: &str) -> Option<(usize, [usize; 3])> {
    match encoding {
        "rgb8" => Some((3, [0, 1, 2])),
        "bgr8" => Some((3, [2, 1, 0])),
        "rgba8" => Some((4, [0, 1, 2])),
        "bgra8" => Some((4, [2, 1, 0])),
        "mono8" | "8UC1" => Some((1, [0, 0, 0])),
        _ => None,
    }
}

/// A raw `sensor_msgs/Image` → RGB. Errors name what is wrong (encoding, sizes, short data).
pub fn rgb_from_image(msg: &Image) -> Result<RgbImage, String> {
    let (channels, [r, g, b]) = layout(&msg.encoding)
        .ok_or_else(|| format!("unsupported image encoding {:?} (rgb8, bgr8, mono8, rgba8, bgra8)", msg.encoding))?;
    let (w, h) = (msg.width as usize, msg.height as usize);
    if w == 0 || h == 0 {
        return Err(format!("empty image ({}×{})", msg.width, msg.height));
    }
    let row = w.checked_mul(channels).ok_or("image row size overflows")?;
    let step = msg.step as usize;
    if step < row {
        return Err(format!("step {step} is shorter than a row ({w} pixels × {channels} bytes)"));
    }
    let needed = step.checked_mul(h - 1).and_then(|n| n.checked_add(row)).ok_or("image size overflows")?;
    if msg.data.len() < needed {
        return Err(format!("{} data bytes, a {w}×{h} {} image needs {needed}", msg.data.len(), msg.encoding));
    }
    let mut out = Vec::with_capacity(w * h * 3);
    for y in 0..h {
        let line = &msg.data[y * step..y * step + row];
        for px in line.chunks_exact(channels) {
            out.extend_from_slice(&[px[r], px[g], px[b]]);
        }
    }
    RgbImage::from_raw(msg.width, msg.height, out).ok_or_else(|| "image buffer size mismatch".to_string())
}

/// Like [`rgb_from_image`], refusing an image over `limits.max_image_side` or
/// `limits.max_image_pixels` before any pixel is copied.
pub fn rgb_from_image_within(msg: &Image, limits: &InputLimits) -> Result<RgbImage, String> {
    check_image_size(&format!("{:?} image", msg.encoding), msg.width, msg.height, limits)?;
    rgb_from_image(msg)
}

/// A `sensor_msgs/CompressedImage` (JPEG, PNG) → RGB, within the default limits.
pub fn rgb_from_compressed(msg: &CompressedImage) -> Result<RgbImage, String> {
    rgb_from_compressed_within(msg, &InputLimits::default())
}

/// Like [`rgb_from_compressed`], within `limits` (see [`decode_within`]).
pub fn rgb_from_compressed_within(msg: &CompressedImage, limits: &InputLimits) -> Result<RgbImage, String> {
    decode_within(&msg.format, &msg.data, limits)
}

/// Bytes the decoders may allocate per pixel of the budget: the widest pixel they produce
/// (16-bit RGBA, 8 bytes), so the budget refuses by pixels, not by the file's pixel type.
const DECODED_BYTES_PER_PIXEL: u64 = 8;

/// A reader of the compressed `data`, its format guessed from the bytes (`format` names it in
/// errors only).
fn reader<'a>(format: &str, data: &'a [u8]) -> Result<image::ImageReader<std::io::Cursor<&'a [u8]>>, String> {
    image::ImageReader::new(std::io::Cursor::new(data))
        .with_guessed_format()
        .map_err(|e| format!("cannot decode the {format:?} image: {e}"))
}

/// Checks the size a compressed image's header declares against `limits.max_image_side` and
/// `limits.max_image_pixels`, decoding nothing: a small file that declares a huge image is
/// refused for the cost of reading its header. Returns the size.
pub fn check_compressed(format: &str, data: &[u8], limits: &InputLimits) -> Result<(u32, u32), String> {
    let (width, height) =
        reader(format, data)?.into_dimensions().map_err(|e| format!("cannot decode the {format:?} image: {e}"))?;
    check_image_size(&format!("{format:?} image"), width, height, limits)?;
    Ok((width, height))
}

/// A compressed image → RGB within `limits`: its header checked first ([`check_compressed`]),
/// then the decoder held to the same side and to `DECODED_BYTES_PER_PIXEL` (8) × the pixel
/// budget, in case the data disagrees with the header.
pub fn decode_within(format: &str, data: &[u8], limits: &InputLimits) -> Result<RgbImage, String> {
    check_compressed(format, data, limits)?;
    let mut reader = reader(format, data)?;
    let mut bounds = image::Limits::default();
    bounds.max_image_width = Some(limits.max_image_side);
    bounds.max_image_height = Some(limits.max_image_side);
    bounds.max_alloc = Some(limits.max_image_pixels.saturating_mul(DECODED_BYTES_PER_PIXEL));
    reader.limits(bounds);
    reader.decode().map(image::DynamicImage::into_rgb8).map_err(|e| {
        format!(
            "cannot decode the {format:?} image: {e} (limits.max_image_side = {}, limits.max_image_pixels = {})",
            limits.max_image_side, limits.max_image_pixels
        )
    })
}

/// The RGB image of a frame's [`CameraImage`]: decoded already, or compressed (decoded here,
/// within `limits` as in the reader).
pub fn from_encoded(image: &CameraImage, limits: &InputLimits) -> Result<RgbImage, String> {
    match image {
        CameraImage::Raw(rgb) => Ok(rgb.clone()),
        CameraImage::Compressed(enc) => decode_within(&enc.format, &enc.data, limits),
    }
}

/// A `sensor_msgs/CompressedImage` → the frame's camera image, kept compressed once its header
/// is within `limits` (the bytes move, nothing is copied or decoded).
pub fn compressed_within(msg: CompressedImage, limits: &InputLimits) -> Result<CameraImage, String> {
    check_compressed(&msg.format, &msg.data, limits)?;
    Ok(CameraImage::Compressed(EncodedImage { format: msg.format, data: msg.data }))
}

/// Draws every correspondence of `all` as a filled 5×5 square: green when it is in `kept`
/// (same pixel), red otherwise. Kept ones are drawn last, so they win where squares overlap.
pub fn draw_matches(img: &mut RgbImage, all: &[Correspondence], kept: &[Correspondence]) {
    let (w, h) = img.dimensions();
    let mut square = |u: f64, v: f64, rgb: [u8; 3]| {
        if !(u.is_finite() && v.is_finite()) {
            return;
        }
        let (cu, cv) = (u.round() as i64, v.round() as i64);
        for y in cv - HALF..=cv + HALF {
            for x in cu - HALF..=cu + HALF {
                if x >= 0 && y >= 0 && x < i64::from(w) && y < i64::from(h) {
                    img.put_pixel(x as u32, y as u32, Rgb(rgb));
                }
            }
        }
    };
    let key = |c: &Correspondence| (c.pixel.x.to_bits(), c.pixel.y.to_bits());
    let kept_set: HashSet<(u64, u64)> = kept.iter().map(key).collect();
    for c in all.iter().filter(|c| !kept_set.contains(&key(c))) {
        square(c.pixel.x, c.pixel.y, REJECTED);
    }
    for c in kept {
        square(c.pixel.x, c.pixel.y, KEPT);
    }
}

/// `img` as a `sensor_msgs/Image` rgb8.
pub fn image_msg(stamp: Stamp, frame_id: &str, img: RgbImage) -> Image {
    let (width, height) = img.dimensions();
    Image {
        header: Header::new(stamp, frame_id),
        height,
        width,
        encoding: "rgb8".into(),
        is_bigendian: 0,
        step: width * 3,
        data: img.into_raw(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3};

    fn corr(u: f64, v: f64) -> Correspondence {
        Correspondence { pixel: Point2::new(u, v), point: Point3::new(0.0, 0.0, 1.0), score: 1.0 }
    }

    fn raw(encoding: &str, w: u32, h: u32, step: u32, data: Vec<u8>) -> Image {
        Image {
            header: Header::new(1, "cam"),
            height: h,
            width: w,
            encoding: encoding.into(),
            is_bigendian: 0,
            step,
            data,
        }
    }

    #[test]
    fn kept_correspondences_are_green_and_rejected_red() {
        let mut img = RgbImage::from_pixel(40, 30, Rgb([10, 10, 10]));
        let (a, b, c) = (corr(5.2, 6.8), corr(20.0, 15.0), corr(39.4, 0.3));
        draw_matches(&mut img, &[a, b, c], &[a, c]);
        assert_eq!(img.get_pixel(5, 7).0, KEPT);
        assert_eq!(img.get_pixel(7, 9).0, KEPT, "corner of the 5×5 square");
        assert_eq!(img.get_pixel(20, 15).0, REJECTED);
        assert_eq!(img.get_pixel(18, 17).0, REJECTED);
        assert_eq!(img.get_pixel(39, 0).0, KEPT, "clipped at the border");
        assert_eq!(img.get_pixel(20, 5).0, [10, 10, 10], "untouched elsewhere");
        assert_eq!(img.get_pixel(10, 7).0, [10, 10, 10]);
        // Non-finite pixels are skipped.
        draw_matches(&mut img, &[corr(f64::NAN, 1.0)], &[]);
    }

    #[test]
    fn raw_encodings_convert_to_rgb() {
        // 2×2, step padded to 8 bytes.
        let bgr = raw("bgr8", 2, 2, 8, vec![1, 2, 3, 4, 5, 6, 0, 0, 7, 8, 9, 10, 11, 12, 0, 0]);
        let img = rgb_from_image(&bgr).unwrap();
        assert_eq!(img.get_pixel(0, 0).0, [3, 2, 1]);
        assert_eq!(img.get_pixel(1, 1).0, [12, 11, 10]);
        let rgb = rgb_from_image(&raw("rgb8", 1, 1, 3, vec![1, 2, 3])).unwrap();
        assert_eq!(rgb.get_pixel(0, 0).0, [1, 2, 3]);
        let mono = rgb_from_image(&raw("mono8", 2, 1, 2, vec![7, 9])).unwrap();
        assert_eq!(mono.get_pixel(1, 0).0, [9, 9, 9]);
        let rgba = rgb_from_image(&raw("rgba8", 1, 1, 4, vec![1, 2, 3, 4])).unwrap();
        assert_eq!(rgba.get_pixel(0, 0).0, [1, 2, 3]);
        let bgra = rgb_from_image(&raw("bgra8", 1, 1, 4, vec![1, 2, 3, 4])).unwrap();
        assert_eq!(bgra.get_pixel(0, 0).0, [3, 2, 1]);
        // Errors, not panics.
        assert!(rgb_from_image(&raw("32FC1", 1, 1, 4, vec![0; 4])).unwrap_err().contains("encoding"));
        assert!(rgb_from_image(&raw("rgb8", 2, 2, 6, vec![0; 11])).unwrap_err().contains("needs 12"));
        assert!(rgb_from_image(&raw("rgb8", 2, 1, 5, vec![0; 6])).unwrap_err().contains("step"));
        assert!(rgb_from_image(&raw("rgb8", 0, 1, 0, vec![])).is_err());
        assert!(rgb_from_image(&raw("rgb8", u32::MAX, u32::MAX, u32::MAX, vec![0; 3])).is_err());
    }

    #[test]
    fn raw_and_compressed_images_round_trip() {
        let mut img = RgbImage::from_pixel(3, 2, Rgb([1, 2, 3]));
        img.put_pixel(2, 1, Rgb([200, 100, 50]));
        let limits = InputLimits::default();
        assert_eq!(from_encoded(&CameraImage::Raw(img.clone()), &limits).unwrap(), img);
        let mut png = Vec::new();
        image::DynamicImage::ImageRgb8(img.clone())
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let msg = CompressedImage { header: Header::new(1, "cam"), format: "png".into(), data: png.clone() };
        assert_eq!(rgb_from_compressed(&msg).unwrap(), img);
        let compressed = crate::frame::EncodedImage { format: "png".into(), data: png };
        assert_eq!(from_encoded(&CameraImage::Compressed(compressed), &limits).unwrap(), img);
        let junk = CompressedImage { header: Header::new(1, "cam"), format: "jpeg".into(), data: vec![1, 2, 3] };
        assert!(rgb_from_compressed(&junk).is_err());
        let wide =
            rgb_from_compressed_within(&msg, &InputLimits { max_image_side: 1, ..Default::default() }).unwrap_err();
        assert!(wide.contains("max_image_side"), "{wide}");
        let junk = crate::frame::EncodedImage { format: "jpeg".into(), data: vec![1, 2, 3] };
        assert!(from_encoded(&CameraImage::Compressed(junk), &limits).unwrap_err().contains("jpeg"));
        let huge = raw("rgb8", 10_000, 10_000, 30_000, vec![0; 3]);
        let side_4096 = InputLimits { max_image_side: 4096, ..Default::default() };
        assert!(rgb_from_image_within(&huge, &side_4096).unwrap_err().contains("max_image_side"));
        let m = image_msg(4, "cam", img);
        assert_eq!((m.width, m.height, m.step, m.encoding.as_str(), m.data.len()), (3, 2, 9, "rgb8", 18));
    }

    /// CRC-32 (IEEE) of a PNG chunk's type and data.
    fn crc32(bytes: &[u8]) -> u32 {
        let mut crc = !0u32;
        for &b in bytes {
            crc ^= u32::from(b);
            for _ in 0..8 {
                crc = if crc & 1 == 1 { (crc >> 1) ^ 0xEDB8_8320 } else { crc >> 1 };
            }
        }
        !crc
    }

    /// A PNG of a few dozen bytes whose header declares a `width`×`height` RGB image (its
    /// pixel data is an empty zlib stream: decoding it would fail, or allocate the image).
    fn png_declaring(width: u32, height: u32) -> Vec<u8> {
        let chunk = |kind: &[u8], data: &[u8]| {
            let body: Vec<u8> = kind.iter().chain(data).copied().collect();
            let mut out = (data.len() as u32).to_be_bytes().to_vec();
            out.extend_from_slice(&body);
            out.extend_from_slice(&crc32(&body).to_be_bytes());
            out
        };
        let mut ihdr = width.to_be_bytes().to_vec();
        ihdr.extend_from_slice(&height.to_be_bytes());
        ihdr.extend_from_slice(&[8, 2, 0, 0, 0]);
        let mut png = b"\x89PNG\r\n\x1a\n".to_vec();
        png.extend(chunk(b"IHDR", &ihdr));
        png.extend(chunk(b"IDAT", &[0x78, 0x9c, 0x03, 0x00, 0x00, 0x00, 0x00, 0x01]));
        png.extend(chunk(b"IEND", &[]));
        png
    }

    /// A 65-byte PNG declaring 100 000 × 100 000 (30 GB decoded) is refused by its header,
    /// in the reader and at drawing time alike, naming the limit and the size.
    #[test]
    fn a_small_png_declaring_a_huge_image_is_refused_by_its_header() {
        let limits = InputLimits::default();
        let data = png_declaring(100_000, 100_000);
        assert!(data.len() < 100, "{} bytes", data.len());
        let started = std::time::Instant::now();
        let err = check_compressed("png", &data, &limits).unwrap_err();
        assert!(err.contains("100000x100000") && err.contains("limits.max_image_side = 8192"), "{err}");
        let msg = CompressedImage { header: Header::new(1, "cam"), format: "png".into(), data: data.clone() };
        assert!(compressed_within(msg.clone(), &limits).unwrap_err().contains("max_image_side"));
        assert!(rgb_from_compressed_within(&msg, &limits).unwrap_err().contains("100000x100000"));
        let kept = CameraImage::Compressed(EncodedImage { format: "png".into(), data });
        assert!(from_encoded(&kept, &limits).unwrap_err().contains("max_image_side"));
        assert!(started.elapsed() < std::time::Duration::from_secs(1), "{:?}", started.elapsed());
    }

    /// Within `limits.max_image_side` (8192) but over `limits.max_image_pixels` (4096²): refused
    /// before decoding, compressed or raw, the error naming the pixel limit and the size.
    #[test]
    fn an_image_over_the_pixel_budget_within_the_side_limit_is_refused() {
        let limits = InputLimits::default();
        let data = png_declaring(8000, 8000);
        for err in [
            check_compressed("png", &data, &limits).unwrap_err(),
            from_encoded(&CameraImage::Compressed(EncodedImage { format: "png".into(), data }), &limits).unwrap_err(),
            rgb_from_image_within(&raw("rgb8", 5000, 5000, 15_000, vec![0; 3]), &limits).unwrap_err(),
        ] {
            assert!(err.contains("limits.max_image_pixels = 16777216") && err.contains("pixels"), "{err}");
            assert!(err.contains("8000x8000") || err.contains("5000x5000"), "{err}");
        }
        // A smaller budget refuses a real image; the same image fits the default one.
        let png = {
            let mut png = Vec::new();
            image::DynamicImage::ImageRgb8(RgbImage::new(40, 30))
                .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
                .expect("png");
            png
        };
        let small = InputLimits { max_image_pixels: 1000, ..Default::default() };
        assert!(check_compressed("png", &png, &small).unwrap_err().contains("(1200 pixels)"));
        assert_eq!(check_compressed("png", &png, &limits), Ok((40, 30)));
        let raw_40x30 = raw("mono8", 40, 30, 40, vec![0; 1200]);
        assert!(rgb_from_image_within(&raw_40x30, &small).unwrap_err().contains("max_image_pixels = 1000"));
        assert!(rgb_from_image_within(&raw_40x30, &limits).is_ok());
    }

    /// The reader keeps a compressed image as it came (its bytes moved, not decoded).
    #[test]
    fn a_compressed_image_within_the_limits_travels_compressed() {
        let mut png = Vec::new();
        image::DynamicImage::ImageRgb8(RgbImage::from_pixel(4, 3, Rgb([9, 8, 7])))
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .expect("png");
        let msg = CompressedImage { header: Header::new(1, "cam"), format: "png".into(), data: png.clone() };
        match compressed_within(msg, &InputLimits::default()) {
            Ok(CameraImage::Compressed(enc)) => assert_eq!((enc.format.as_str(), enc.data), ("png", png)),
            other => panic!("not kept compressed: {other:?}"),
        }
    }
}

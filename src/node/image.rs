//! Camera images of the node: `sensor_msgs/Image` (`rgb8`, `bgr8`, `mono8`, `rgba8`, `bgra8`)
//! or `sensor_msgs/CompressedImage` (JPEG/PNG), converted in the reader threads to RGB, and the
//! debug image (kept correspondences green, rejected red) drawn on it.
//!
//! A converted image travels in the frame as a [`CameraImage::Raw`], so the worker never
//! decodes.

use std::collections::HashSet;

use image::{Rgb, RgbImage};

use crate::frame::{CameraImage, Correspondence, Stamp};
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

/// Like [`rgb_from_image`], refusing an image wider or taller than `max_side` before any
/// pixel is copied.
pub fn rgb_from_image_within(msg: &Image, max_side: u32) -> Result<RgbImage, String> {
    if msg.width > max_side || msg.height > max_side {
        return Err(format!(
            "image of {}x{} exceeds limits.max_image_side = {max_side} (refused)",
            msg.width, msg.height
        ));
    }
    rgb_from_image(msg)
}

/// A `sensor_msgs/CompressedImage` (JPEG, PNG) → RGB.
pub fn rgb_from_compressed(msg: &CompressedImage) -> Result<RgbImage, String> {
    rgb_from_compressed_within(msg, crate::limits::InputLimits::default().max_image_side)
}

/// Like [`rgb_from_compressed`], refusing an image wider or taller than `max_side` (its header
/// is read before any pixel is decoded, so a small file declaring a huge image costs nothing).
pub fn rgb_from_compressed_within(msg: &CompressedImage, max_side: u32) -> Result<RgbImage, String> {
    let fail = |e: image::ImageError| format!("cannot decode the {:?} image: {e}", msg.format);
    let mut reader =
        image::ImageReader::new(std::io::Cursor::new(&msg.data)).with_guessed_format().map_err(|e| fail(e.into()))?;
    let mut limits = image::Limits::default();
    limits.max_image_width = Some(max_side);
    limits.max_image_height = Some(max_side);
    limits.max_alloc = Some(u64::from(max_side) * u64::from(max_side) * 4);
    reader.limits(limits);
    reader.decode().map(|img| img.to_rgb8()).map_err(|e| format!("{} (limits.max_image_side = {max_side})", fail(e)))
}

/// The RGB image of a frame's [`CameraImage`]: decoded already, or compressed (decoded here).
pub fn from_encoded(image: &CameraImage) -> Result<RgbImage, String> {
    match image {
        CameraImage::Raw(rgb) => Ok(rgb.clone()),
        CameraImage::Compressed(enc) => image::load_from_memory(&enc.data)
            .map(|img| img.to_rgb8())
            .map_err(|e| format!("cannot decode the {:?} image: {e}", enc.format)),
    }
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
        assert_eq!(from_encoded(&CameraImage::Raw(img.clone())).unwrap(), img);
        let mut png = Vec::new();
        image::DynamicImage::ImageRgb8(img.clone())
            .write_to(&mut std::io::Cursor::new(&mut png), image::ImageFormat::Png)
            .unwrap();
        let msg = CompressedImage { header: Header::new(1, "cam"), format: "png".into(), data: png.clone() };
        assert_eq!(rgb_from_compressed(&msg).unwrap(), img);
        let compressed = crate::frame::EncodedImage { format: "png".into(), data: png };
        assert_eq!(from_encoded(&CameraImage::Compressed(compressed)).unwrap(), img);
        let junk = CompressedImage { header: Header::new(1, "cam"), format: "jpeg".into(), data: vec![1, 2, 3] };
        assert!(rgb_from_compressed(&junk).is_err());
        let wide = rgb_from_compressed_within(&msg, 1).unwrap_err();
        assert!(wide.contains("max_image_side"), "{wide}");
        let junk = crate::frame::EncodedImage { format: "jpeg".into(), data: vec![1, 2, 3] };
        assert!(from_encoded(&CameraImage::Compressed(junk)).unwrap_err().contains("jpeg"));
        let huge = raw("rgb8", 10_000, 10_000, 30_000, vec![0; 3]);
        assert!(rgb_from_image_within(&huge, 4096).unwrap_err().contains("max_image_side"));
        let m = image_msg(4, "cam", img);
        assert_eq!((m.width, m.height, m.step, m.encoding.as_str(), m.data.len()), (3, 2, 9, "rgb8", 18));
    }
}

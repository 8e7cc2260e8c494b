//! Figures drawn once for both back ends (PNG through an RGB buffer, SVG as text), the compiled-in
//! font, and the colours every figure gives a method.

use std::path::Path;
use std::sync::OnceLock;

use image::RgbImage;
use plotters::coord::Shift;
use plotters::prelude::*;

use super::ReportError;

/// The font family every figure's text uses; registered from the compiled-in font.
pub const FONT: &str = "sans-serif";
const FONT_BYTES: &[u8] = include_bytes!("LiberationSans-Regular.ttf");

/// Registers the compiled-in font for [`FONT`] (once per process).
pub fn register_font() -> Result<(), ReportError> {
    static REGISTERED: OnceLock<bool> = OnceLock::new();
    let ok = *REGISTERED.get_or_init(|| {
        plotters::style::register_font(FONT, FontStyle::Normal, FONT_BYTES).is_ok()
            && plotters::style::register_font(FONT, FontStyle::Bold, FONT_BYTES).is_ok()
    });
    if ok {
        Ok(())
    } else {
        Err(ReportError::Font)
    }
}

/// The result of drawing on a back end `DB`.
pub type DrawResult<DB> = Result<(), DrawingAreaErrorKind<<DB as DrawingBackend>::ErrorType>>;

/// A figure that draws itself on any plotters back end.
pub trait Figure {
    /// Width and height in pixels.
    fn size(&self) -> (u32, u32);
    fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB>;
}

/// Colour of the `index`-th method (distinct for the first eight, then repeating).
pub fn method_colour(index: usize) -> RGBColor {
    const PALETTE: [RGBColor; 8] = [
        RGBColor(31, 119, 180),
        RGBColor(255, 127, 14),
        RGBColor(148, 103, 189),
        RGBColor(23, 190, 207),
        RGBColor(140, 86, 75),
        RGBColor(227, 119, 194),
        RGBColor(188, 189, 34),
        RGBColor(127, 127, 127),
    ];
    PALETTE[index % PALETTE.len()]
}

/// Renders `figure` to `<stem>.png` and `<stem>.svg` in `dir`; returns the two file names.
pub fn write_png_and_svg(figure: &impl Figure, dir: &Path, stem: &str) -> Result<[String; 2], ReportError> {
    let draw_error = |e: &dyn std::fmt::Display| ReportError::Draw { figure: stem.to_string(), message: e.to_string() };
    let png = format!("{stem}.png");
    save_png(&render_bitmap(figure).map_err(|e| draw_error(&e))?, &dir.join(&png), Compression::Small)?;
    let svg = format!("{stem}.svg");
    let mut text = String::new();
    {
        let root = SVGBackend::with_string(&mut text, figure.size()).into_drawing_area();
        root.fill(&WHITE).map_err(|e| draw_error(&e))?;
        figure.draw(&root).map_err(|e| draw_error(&e))?;
        root.present().map_err(|e| draw_error(&e))?;
    }
    let path = dir.join(&svg);
    std::fs::write(&path, text).map_err(|source| ReportError::Io { path, source })?;
    Ok([png, svg])
}

/// `figure` drawn into an RGB image.
pub fn render_bitmap(figure: &impl Figure) -> Result<RgbImage, String> {
    let (w, h) = figure.size();
    let mut buffer = vec![255u8; w as usize * h as usize * 3];
    {
        let root = BitMapBackend::with_buffer(&mut buffer, (w, h)).into_drawing_area();
        figure.draw(&root).map_err(|e| e.to_string())?;
        root.present().map_err(|e| e.to_string())?;
    }
    RgbImage::from_raw(w, h, buffer).ok_or_else(|| format!("a {w}×{h} buffer of the wrong size"))
}

/// How hard the PNG encoder works: plots shrink a lot with [`Compression::Small`], photos hardly.
#[derive(Clone, Copy, Debug)]
pub enum Compression {
    Small,
    Fast,
}

pub fn save_png(img: &RgbImage, path: &Path, compression: Compression) -> Result<(), ReportError> {
    use image::codecs::png::{CompressionType, FilterType, PngEncoder};
    use image::ImageEncoder;
    let encode_error = |message: String| ReportError::Encode { path: path.to_path_buf(), message };
    let mut bytes = Vec::new();
    let (level, filter) = match compression {
        Compression::Small => (CompressionType::Best, FilterType::Adaptive),
        Compression::Fast => (CompressionType::Fast, FilterType::Sub),
    };
    PngEncoder::new_with_quality(&mut bytes, level, filter)
        .write_image(img.as_raw(), img.width(), img.height(), image::ExtendedColorType::Rgb8)
        .map_err(|e| encode_error(e.to_string()))?;
    std::fs::write(path, bytes).map_err(|source| ReportError::Io { path: path.to_path_buf(), source })
}

/// A value range that plots well: `lo..hi` padded by `pad` of its span, never empty.
pub fn padded(lo: f64, hi: f64, pad: f64) -> std::ops::Range<f64> {
    if !(lo.is_finite() && hi.is_finite()) || hi < lo {
        return 0.0..1.0;
    }
    let span = (hi - lo).max(1e-9);
    let margin = if hi - lo < 1e-9 { 0.5 } else { span * pad };
    (lo - margin)..(hi + margin)
}

#[cfg(test)]
mod tests {
    use super::*;

    struct Square;
    impl Figure for Square {
        fn size(&self) -> (u32, u32) {
            (120, 80)
        }
        fn draw<DB: DrawingBackend>(&self, root: &DrawingArea<DB, Shift>) -> DrawResult<DB> {
            root.fill(&WHITE)?;
            root.draw(&Rectangle::new([(10, 10), (30, 30)], RED.filled()))?;
            root.draw(&Text::new("axis", (40, 40), (FONT, 20).into_font().color(&BLACK)))
        }
    }

    #[test]
    fn figures_render_with_the_compiled_in_font() {
        register_font().unwrap();
        let img = render_bitmap(&Square).unwrap();
        assert_eq!(img.dimensions(), (120, 80));
        assert_eq!(img.get_pixel(20, 20).0, [255, 0, 0]);
        // The text left dark pixels: the font was found and rasterised.
        let dark =
            (40..110).flat_map(|x| (35..75).map(move |y| (x, y))).filter(|&(x, y)| img.get_pixel(x, y).0[0] < 100);
        assert!(dark.count() > 20, "no text drawn");
        let dir = tempfile::tempdir().unwrap();
        let names = write_png_and_svg(&Square, dir.path(), "square").unwrap();
        let svg = std::fs::read_to_string(dir.path().join(&names[1])).unwrap();
        assert!(svg.contains("<svg") && svg.contains("axis"));
        assert_eq!(image::open(dir.path().join(&names[0])).unwrap().to_rgb8(), img);
    }

    #[test]
    fn padded_ranges_are_never_empty() {
        assert_eq!(padded(1.0, 1.0, 0.1), 0.5..1.5);
        assert_eq!(padded(f64::NAN, 1.0, 0.1), 0.0..1.0);
        let r = padded(0.0, 10.0, 0.1);
        assert!((r.start + 1.0).abs() < 1e-12 && (r.end - 11.0).abs() < 1e-12);
    }
}

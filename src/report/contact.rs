//! A contact sheet of one method's worst and best frames: each camera image with the node's
//! debug drawing (kept correspondences green, rejected red: `node::image::draw_matches`) and a
//! ring around every true inlier (ground truth, the IR's 5 cm rule), captioned with the errors.

use image::{imageops, Rgb, RgbImage};
use plotters::prelude::*;

use super::data::{Outcome, ScoredFrame, ScoredRun};
use super::figure::{method_colour, FONT};
use super::ReportError;
use crate::bag::BagFrames;
use crate::eval::inlier_mask;
use crate::frame::{Correspondence, Frame};
use crate::node::image::{draw_matches, from_encoded};

/// Frames per row (worst row, best row).
const PER_ROW: usize = 4;
const TILE_WIDTH: u32 = 320;
const GAP: u32 = 12;
const HEADER: u32 = 58;
const ROW_TITLE: u32 = 28;
const CAPTION: u32 = 74;
/// Characters per caption line.
const LINE_CHARS: usize = 46;
pub const RING: RGBColor = RGBColor(0, 180, 255);
const RING_RADIUS: i32 = 5;

/// One tile: the frame, drawn and scaled, and where its true inliers are on it.
struct Tile<'a> {
    scored: &'a ScoredFrame,
    image: RgbImage,
    rings: Vec<(i32, i32)>,
    note: Option<String>,
}

/// The contact sheet of `run` (the `index`-th method) over `bag`'s frames.
pub fn contact_sheet(bag: &BagFrames, run: &ScoredRun, index: usize) -> Result<RgbImage, ReportError> {
    let (worst, best) = worst_and_best(&run.frames, PER_ROW);
    let rows = [
        ("worst frames: no pose first, then highest RMSE", worst.iter().map(|f| tile(bag, f)).collect::<Vec<_>>()),
        ("best frames: lowest RMSE", best.iter().map(|f| tile(bag, f)).collect()),
    ];
    let width = GAP + PER_ROW as u32 * (TILE_WIDTH + GAP);
    let mut layout = Vec::new();
    let mut titles = Vec::new();
    let mut y = HEADER;
    for (title, tiles) in &rows {
        titles.push((*title, y as i32));
        for (k, t) in tiles.iter().enumerate() {
            layout.push(((GAP + k as u32 * (TILE_WIDTH + GAP)) as i32, (y + ROW_TITLE) as i32, t));
        }
        y += ROW_TITLE + tiles.iter().map(|t| t.image.height()).max().unwrap_or(0) + CAPTION + GAP;
    }
    let mut canvas = RgbImage::from_pixel(width, y, Rgb([255, 255, 255]));
    for (x, y, t) in &layout {
        imageops::overlay(&mut canvas, &t.image, i64::from(*x), i64::from(*y));
    }
    let title = format!("{}: worst and best frames", run.label);
    annotate(&mut canvas, &title, method_colour(index), &titles, &layout, first_stamp(bag, run))
        .map_err(|message| ReportError::Draw { figure: format!("contact sheet of {}", run.label), message })?;
    Ok(canvas)
}

fn first_stamp(bag: &BagFrames, run: &ScoredRun) -> i64 {
    run.frames.first().and_then(|f| bag.frames.get(f.frame_index)).map_or(0, |f| f.stamp)
}

/// The `n` worst frames (worst first) and the `n` best (best first), disjoint.
fn worst_and_best(frames: &[ScoredFrame], n: usize) -> (Vec<&ScoredFrame>, Vec<&ScoredFrame>) {
    let mut order: Vec<&ScoredFrame> = frames.iter().collect();
    order.sort_by(|a, b| a.rank_error().total_cmp(&b.rank_error()).then(a.frame_index.cmp(&b.frame_index)));
    let best: Vec<&ScoredFrame> = order.iter().take(n.min(order.len().div_ceil(2))).copied().collect();
    let worst: Vec<&ScoredFrame> = order.iter().rev().take(n.min(order.len() - best.len())).copied().collect();
    (worst, best)
}

/// The frame's image scaled to the tile width, with matches drawn and true inliers located.
fn tile<'a>(bag: &BagFrames, scored: &'a ScoredFrame) -> Tile<'a> {
    let Some(frame) = bag.frames.get(scored.frame_index) else {
        return blank(scored, "frame not in the input bag".into());
    };
    let decoded = match &frame.image {
        // Within the default image limits (4096 × 4096 pixels): a report gets no parameters,
        // and a tile is 320 pixels wide anyway.
        Some(enc) => from_encoded(enc, &crate::limits::InputLimits::default()),
        None => Err("the frame has no camera image".to_string()),
    };
    let image = match decoded {
        Ok(img) if img.width() > 0 && img.height() > 0 => img,
        Ok(_) => return blank(scored, "empty camera image".into()),
        Err(reason) => return blank(scored, reason),
    };
    let scale = f64::from(TILE_WIDTH) / f64::from(image.width());
    let height = ((f64::from(image.height()) * scale).round() as u32).clamp(1, 4 * TILE_WIDTH);
    let mut image = imageops::resize(&image, TILE_WIDTH, height, imageops::FilterType::Triangle);
    let scaled = |c: &[Correspondence]| -> Vec<Correspondence> {
        c.iter().map(|c| Correspondence { pixel: nalgebra::Point2::from(c.pixel.coords * scale), ..*c }).collect()
    };
    draw_matches(&mut image, &scaled(&frame.correspondences), &scaled(&scored.record.kept));
    let rings = true_inliers(frame)
        .into_iter()
        .filter(|c| c.pixel.x.is_finite() && c.pixel.y.is_finite())
        .map(|c| ((c.pixel.x * scale).round() as i32, (c.pixel.y * scale).round() as i32))
        .collect();
    Tile { scored, image, rings, note: None }
}

fn true_inliers(frame: &Frame) -> Vec<&Correspondence> {
    let Some((pose, depth)) = frame.ground_truth.as_ref().and_then(|g| Some((g.pose.as_ref()?, g.depth.as_ref()?)))
    else {
        return Vec::new();
    };
    let mask = inlier_mask(&frame.correspondences, &frame.intrinsics, pose, depth);
    frame.correspondences.iter().zip(mask).filter(|(_, (inlier, valid))| *inlier && *valid).map(|(c, _)| c).collect()
}

fn blank(scored: &ScoredFrame, note: String) -> Tile<'_> {
    let image = RgbImage::from_pixel(TILE_WIDTH, TILE_WIDTH * 3 / 4, Rgb([225, 225, 225]));
    Tile { scored, image, rings: Vec::new(), note: Some(note) }
}

/// Title, legend, row titles, rings and captions, drawn over the composed sheet.
fn annotate(
    canvas: &mut RgbImage,
    title: &str,
    colour: RGBColor,
    titles: &[(&str, i32)],
    layout: &[(i32, i32, &Tile)],
    t0: i64,
) -> Result<(), String> {
    let (w, h) = canvas.dimensions();
    let root = BitMapBackend::with_buffer(canvas.as_mut(), (w, h)).into_drawing_area();
    let font = |size: u32| (FONT, size).into_font().color(&BLACK);
    let e = |e: DrawingAreaErrorKind<_>| e.to_string();
    root.draw(&Rectangle::new([(GAP as i32, 10), (GAP as i32 + 14, 24)], colour.filled())).map_err(e)?;
    root.draw(&Text::new(title, (GAP as i32 + 22, 8), font(20))).map_err(e)?;
    let legend = "green square: kept · red square: rejected · blue ring: true inlier (ground-truth depth, 5 cm)";
    root.draw(&Text::new(legend, (GAP as i32, 34), font(15))).map_err(e)?;
    for (text, y) in titles {
        root.draw(&Text::new(*text, (GAP as i32, y + 6), font(16))).map_err(e)?;
    }
    for (x, y, t) in layout {
        for (u, v) in &t.rings {
            root.draw(&Circle::new((x + u, y + v), RING_RADIUS, RING.stroke_width(1))).map_err(e)?;
        }
        let below = y + t.image.height() as i32 + 4;
        for (k, line) in caption(t, t0).iter().enumerate() {
            root.draw(&Text::new(line.as_str(), (*x, below + 17 * k as i32), font(14))).map_err(e)?;
        }
    }
    root.present().map_err(e)
}

fn caption(t: &Tile, t0: i64) -> Vec<String> {
    let s = t.scored;
    let seconds = (s.metrics.stamp - t0) as f64 * 1e-9;
    let mut lines = vec![format!("frame {} · t = {seconds:.2} s", s.frame_index)];
    match (s.outcome(), s.metrics.errors) {
        (Outcome::NoPose, _) | (_, None) => {
            let reason = s.record.failure.as_deref().unwrap_or("none in the output bag");
            lines.extend(wrap(&format!("no pose: {reason}"), LINE_CHARS, 2));
        }
        (_, Some(e)) => {
            lines.push(format!("RMSE {:.3} m · {:.2}° · {:.3} m", e.rmse_m, e.rotation_deg, e.translation_m))
        }
    }
    lines.push(match &t.note {
        Some(note) => note.chars().take(LINE_CHARS).collect(),
        None => {
            format!(
                "kept {}, {} of them true · true in all: {} (ringed)",
                s.record.kept.len(),
                s.true_inliers_kept,
                t.rings.len()
            )
        }
    });
    lines
}

/// `text` in at most `max_lines` lines of at most `width` characters, broken at spaces; what
/// does not fit ends in `…`.
fn wrap(text: &str, width: usize, max_lines: usize) -> Vec<String> {
    let mut lines: Vec<String> = Vec::new();
    let mut current = String::new();
    for word in text.split_whitespace() {
        let fits = current.chars().count() + 1 + word.chars().count() <= width;
        if !current.is_empty() && !fits {
            lines.push(std::mem::take(&mut current));
        }
        if !current.is_empty() {
            current.push(' ');
        }
        current.push_str(word);
    }
    if !current.is_empty() {
        lines.push(current);
    }
    if lines.len() > max_lines {
        lines.truncate(max_lines);
        if let Some(last) = lines.last_mut() {
            last.push('…');
        }
    }
    for line in &mut lines {
        if line.chars().count() > width + 1 {
            *line = line.chars().take(width).chain(['…']).collect();
        }
    }
    lines
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::eval::{FrameMetrics, PoseErrors};

    fn scored(k: usize, rmse: Option<f64>) -> ScoredFrame {
        let errors = rmse.map(|r| PoseErrors { rotation_deg: r, translation_m: r, rmse_m: r, nees: None });
        ScoredFrame {
            frame_index: k,
            metrics: FrameMetrics { stamp: k as i64, inlier_ratio: 0.0, errors, ms: None },
            record: Default::default(),
            true_inliers_kept: 0,
        }
    }

    #[test]
    fn captions_wrap_at_spaces() {
        assert_eq!(wrap("no pose: PnP failed", 12, 2), ["no pose: PnP", "failed"]);
        assert_eq!(wrap("a b c d e f", 3, 2), ["a b", "c d…"]);
        assert_eq!(wrap("abcdefghij", 4, 2), ["abcd…"]);
        assert!(wrap("", 4, 2).is_empty());
    }

    #[test]
    fn worst_and_best_are_ordered_and_disjoint() {
        let frames: Vec<ScoredFrame> = [Some(0.3), None, Some(0.01), Some(2.0), Some(0.05)]
            .iter()
            .enumerate()
            .map(|(k, r)| scored(k, *r))
            .collect();
        let (worst, best) = worst_and_best(&frames, 2);
        assert_eq!(worst.iter().map(|f| f.frame_index).collect::<Vec<_>>(), [1, 3]);
        assert_eq!(best.iter().map(|f| f.frame_index).collect::<Vec<_>>(), [2, 4]);
        let (worst, best) = worst_and_best(&frames[..3], 4);
        assert_eq!((worst.len(), best.len()), (1, 2));
        assert_eq!(worst[0].frame_index, 1);
        let (worst, best) = worst_and_best(&[], 4);
        assert!(worst.is_empty() && best.is_empty());
    }
}

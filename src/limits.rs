//! Input limits: how much one message may make angle-i2p hold or compute, applied at the edge
//! where a message becomes a frame part or a map. Every limit hit is counted and said — in the
//! frame's issues or the map's — and never aborts a run.
//!
//! What happens beyond each limit:
//! * correspondences per frame: the best `max_correspondences` by score are kept;
//! * exact duplicate correspondences (same pixel and point) are counted over the run; when they
//!   are more than `merge_duplicates_above` of a frame's correspondences (a matcher repeating
//!   its output, which biases rejection and PnP), they are merged, keeping the best score, and
//!   the frame says so. Real matchers emit a few (up to 8 % of a frame in the shared bags), left as they are;
//! * scores outside [0, 1] are clamped into it;
//! * a CameraInfo, depth prior or ground-truth depth wider or taller than `max_image_side`
//!   is refused (that part fails with the reason);
//! * a depth prior, ground-truth depth or camera image of the live node (`node.debug_image`)
//!   of more than `max_image_pixels` pixels is refused before it is converted or decoded (a
//!   compressed one by its header);
//! * a map with more than `max_map_points` finite points keeps an even subsample;
//!   non-finite map points are dropped;
//! * a record (or decompressed chunk) over `max_record_bytes` makes the bag an error;
//! * at most `max_pending_frames` frames wait for missing parts; the oldest is handed out as
//!   incomplete beyond it.

use serde::{Deserialize, Serialize};

use crate::frame::{Correspondence, MapCloud};

/// Default `max_record_bytes` (and `bag::ReadOptions`'): 256 MiB (an 8192 × 8192 32FC1 image
/// and its header).
pub const DEFAULT_MAX_RECORD_BYTES: u64 = 256 << 20;

/// Default `max_image_pixels`: 4096 × 4096.
pub const DEFAULT_MAX_IMAGE_PIXELS: u64 = 4096 * 4096;

/// The `limits` section of the parameters.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct InputLimits {
    /// Correspondences kept per frame (the best by score).
    pub max_correspondences: usize,
    /// Largest width or height of a CameraInfo, depth prior, ground-truth depth or camera image.
    pub max_image_side: u32,
    /// Most pixels (width × height) of a depth prior, ground-truth depth or camera image
    /// converted or decoded: a square image at `max_image_side` alone is 67 M pixels (201 MB as
    /// RGB, 268 MB as a float depth), and 200 KB PNGs of it made the node hold 1.9–2.4 GB (#38).
    /// The default, 4096 × 4096, is 50 MB as RGB (64 MB as depth), 2× a 12 MP camera's.
    pub max_image_pixels: u64,
    /// Map points kept (an even subsample beyond it).
    pub max_map_points: usize,
    /// Longest MCAP record or decompressed chunk read from a bag (bytes).
    pub max_record_bytes: u64,
    /// Frames waiting for parts at once while reading a bag.
    pub max_pending_frames: usize,
    /// Merge a frame's exact duplicate correspondences (same pixel and point; the best score
    /// stays) when they are more than this share of them: 0 always, 1 never.
    pub merge_duplicates_above: f64,
}

impl Default for InputLimits {
    fn default() -> Self {
        Self {
            max_correspondences: 5000,
            max_image_side: 8192,
            max_image_pixels: DEFAULT_MAX_IMAGE_PIXELS,
            max_map_points: 5_000_000,
            max_record_bytes: DEFAULT_MAX_RECORD_BYTES,
            max_pending_frames: 256,
            merge_duplicates_above: 0.25,
        }
    }
}

/// What [`limit_correspondences`] changed.
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct CorrespondenceFixes {
    /// Exact duplicates found (each beyond its first occurrence).
    pub duplicates: usize,
    /// Whether they were merged.
    pub merged: bool,
    pub scores_clamped: usize,
    /// Correspondences left out beyond the limit (the lowest scores).
    pub over_limit: usize,
}

impl CorrespondenceFixes {
    /// One line per anomaly, for the frame's issues. A few duplicates are not one (real
    /// matchers emit them): they are only counted over the run ([`LimitCounts`]).
    pub fn notes(&self, limits: &InputLimits) -> Vec<String> {
        let mut out = Vec::new();
        if self.scores_clamped > 0 {
            out.push(format!("correspondences: {} scores outside [0, 1] clamped", self.scores_clamped));
        }
        if self.merged {
            out.push(format!(
                "correspondences: {} exact duplicates merged (over limits.merge_duplicates_above = {})",
                self.duplicates, limits.merge_duplicates_above
            ));
        }
        if self.over_limit > 0 {
            out.push(format!(
                "correspondences: kept the best {} by score, left out {} (limits.max_correspondences)",
                limits.max_correspondences, self.over_limit
            ));
        }
        out
    }
}

/// What the limits changed over a run (frames counted once per kind of change).
#[derive(Clone, Debug, Default, PartialEq, Eq)]
pub struct LimitCounts {
    pub frames_with_duplicates: usize,
    pub duplicates: usize,
    pub frames_with_duplicates_merged: usize,
    pub frames_with_scores_clamped: usize,
    pub frames_over_correspondence_limit: usize,
}

impl LimitCounts {
    pub fn add(&mut self, fixes: &CorrespondenceFixes) {
        self.frames_with_duplicates += (fixes.duplicates > 0) as usize;
        self.duplicates += fixes.duplicates;
        self.frames_with_duplicates_merged += fixes.merged as usize;
        self.frames_with_scores_clamped += (fixes.scores_clamped > 0) as usize;
        self.frames_over_correspondence_limit += (fixes.over_limit > 0) as usize;
    }

    /// Summary lines for a run's report (empty when nothing changed).
    pub fn summary(&self) -> Vec<String> {
        let mut out = Vec::new();
        if self.duplicates > 0 {
            out.push(format!(
                "{} frames had exact duplicate correspondences ({} in all); merged in {} frames where they were \
                 over limits.merge_duplicates_above",
                self.frames_with_duplicates, self.duplicates, self.frames_with_duplicates_merged
            ));
        }
        if self.frames_with_scores_clamped > 0 {
            out.push(format!("{} frames had scores outside [0, 1], clamped", self.frames_with_scores_clamped));
        }
        if self.frames_over_correspondence_limit > 0 {
            out.push(format!(
                "{} frames had more correspondences than limits.max_correspondences; the best by score were kept",
                self.frames_over_correspondence_limit
            ));
        }
        out
    }
}

/// Clamps scores, merges exact duplicates (first position, best score) and keeps the best
/// `max_correspondences` by score, in their original order.
pub fn limit_correspondences(c: &mut Vec<Correspondence>, limits: &InputLimits) -> CorrespondenceFixes {
    let mut fixes = CorrespondenceFixes::default();
    for x in c.iter_mut() {
        if !(0.0..=1.0).contains(&x.score) {
            x.score = x.score.clamp(0.0, 1.0);
            fixes.scores_clamped += 1;
        }
    }
    fixes.duplicates = count_duplicates(c);
    if fixes.duplicates > 0 && fixes.duplicates as f64 > limits.merge_duplicates_above * c.len() as f64 {
        merge_duplicates(c);
        fixes.merged = true;
    }
    if c.len() > limits.max_correspondences {
        let mut order: Vec<usize> = (0..c.len()).collect();
        // Best score first; ties keep the earlier one.
        order.sort_by(|&a, &b| c[b].score.total_cmp(&c[a].score).then(a.cmp(&b)));
        let mut chosen = vec![false; c.len()];
        for &i in order.iter().take(limits.max_correspondences) {
            chosen[i] = true;
        }
        fixes.over_limit = c.len() - limits.max_correspondences;
        let mut flags = chosen.into_iter();
        c.retain(|_| flags.next().unwrap_or(false));
    }
    fixes
}

/// The identity of a correspondence: its pixel and point, bit for bit (±0 alike).
fn duplicate_key(x: &Correspondence) -> [u64; 5] {
    [x.pixel.x, x.pixel.y, x.point.x, x.point.y, x.point.z].map(|v| if v == 0.0 { 0 } else { v.to_bits() })
}

/// Exact duplicates in `c`, each beyond its first occurrence.
fn count_duplicates(c: &[Correspondence]) -> usize {
    let mut seen = std::collections::HashSet::with_capacity(c.len());
    c.iter().filter(|x| !seen.insert(duplicate_key(x))).count()
}

/// Merges exact duplicates into their first occurrence (keeping the best score); returns how
/// many were merged.
fn merge_duplicates(c: &mut Vec<Correspondence>) -> usize {
    let key = duplicate_key;
    let mut first: std::collections::HashMap<[u64; 5], usize> = std::collections::HashMap::with_capacity(c.len());
    let mut keep = vec![true; c.len()];
    let mut merged = 0;
    for i in 0..c.len() {
        match first.entry(key(&c[i])) {
            std::collections::hash_map::Entry::Vacant(v) => {
                v.insert(i);
            }
            std::collections::hash_map::Entry::Occupied(o) => {
                let j = *o.get();
                c[j].score = c[j].score.max(c[i].score);
                keep[i] = false;
                merged += 1;
            }
        }
    }
    if merged > 0 {
        let mut flags = keep.into_iter();
        c.retain(|_| flags.next().unwrap_or(true));
    }
    merged
}

/// Checks an image size against `max_image_side`; the error says which limit and the size.
pub fn check_image_side(what: &str, width: u32, height: u32, limits: &InputLimits) -> Result<(), String> {
    if width > limits.max_image_side || height > limits.max_image_side {
        return Err(format!(
            "{what} of {width}x{height} exceeds limits.max_image_side = {} (refused)",
            limits.max_image_side
        ));
    }
    Ok(())
}

/// Checks an image's pixel count (width × height) against `max_image_pixels`; the error says
/// which limit and the size.
pub fn check_image_pixels(what: &str, width: u32, height: u32, limits: &InputLimits) -> Result<(), String> {
    let pixels = u64::from(width) * u64::from(height);
    if pixels > limits.max_image_pixels {
        return Err(format!(
            "{what} of {width}x{height} ({pixels} pixels) exceeds limits.max_image_pixels = {} (refused)",
            limits.max_image_pixels
        ));
    }
    Ok(())
}

/// Both [`check_image_side`] and [`check_image_pixels`], for an image about to be decoded.
pub fn check_image_size(what: &str, width: u32, height: u32, limits: &InputLimits) -> Result<(), String> {
    check_image_side(what, width, height, limits)?;
    check_image_pixels(what, width, height, limits)
}

/// Keeps an even subsample of at most `max_map_points` points (every k-th, by a fixed stride
/// over the cloud's order); returns how many were left out.
pub fn limit_map(map: &mut MapCloud, limits: &InputLimits) -> usize {
    let (n, max) = (map.points.len(), limits.max_map_points);
    if n <= max {
        return 0;
    }
    if max == 0 {
        map.points.clear();
        return n;
    }
    // Point i is kept when floor(i·max/n) steps: exactly `max` points, evenly spread.
    let mut next = 0usize;
    let mut kept = Vec::with_capacity(max);
    for (i, p) in map.points.iter().enumerate() {
        if i * max / n >= next && kept.len() < max {
            kept.push(*p);
            next += 1;
        }
    }
    map.points = kept;
    n - max
}

#[cfg(test)]
mod tests {
    use super::*;
    use nalgebra::{Point2, Point3};

    fn c(u: f64, score: f32) -> Correspondence {
        Correspondence { pixel: Point2::new(u, 1.0), point: Point3::new(u, 2.0, 3.0), score }
    }

    #[test]
    fn duplicates_merge_scores_clamp_and_the_best_are_kept_in_order() {
        let limits = InputLimits { max_correspondences: 2, merge_duplicates_above: 0.0, ..Default::default() };
        let mut v = vec![c(1.0, 0.2), c(2.0, 1e30), c(1.0, 0.9), c(3.0, -5.0), c(4.0, 0.5)];
        let fixes = limit_correspondences(&mut v, &limits);
        let want = CorrespondenceFixes { duplicates: 1, merged: true, scores_clamped: 2, over_limit: 2 };
        assert_eq!(fixes, want);
        assert_eq!(v, vec![c(1.0, 0.9), c(2.0, 1.0)]);
        assert_eq!(fixes.notes(&limits).len(), 3);
        let mut counts = LimitCounts::default();
        counts.add(&fixes);
        assert_eq!(counts.summary().len(), 3);
    }

    #[test]
    fn a_few_duplicates_are_counted_and_left_many_are_merged() {
        let few: Vec<Correspondence> = (0..20).map(|i| c(i as f64, 0.5)).chain([c(0.0, 0.9)]).collect();
        let mut v = few.clone();
        let fixes = limit_correspondences(&mut v, &InputLimits::default());
        assert_eq!((fixes.duplicates, fixes.merged, v.len()), (1, false, 21));
        assert!(fixes.notes(&InputLimits::default()).is_empty(), "a few duplicates are no anomaly");
        let mut tenfold: Vec<Correspondence> = few.iter().flat_map(|x| std::iter::repeat_n(*x, 10)).collect();
        let fixes = limit_correspondences(&mut tenfold, &InputLimits::default());
        assert_eq!((fixes.duplicates, fixes.merged, tenfold.len()), (190, true, 20));
        assert_eq!(tenfold[0].score, 0.9, "the best score of a merged group stays");
    }

    #[test]
    fn clean_input_is_untouched() {
        let mut v = vec![c(1.0, 0.2), c(2.0, 0.3)];
        let before = v.clone();
        assert_eq!(limit_correspondences(&mut v, &InputLimits::default()), CorrespondenceFixes::default());
        assert_eq!(v, before);
    }

    #[test]
    fn map_subsample_is_even_and_exact() {
        let points: Vec<Point3<f32>> = (0..10).map(|i| Point3::new(i as f32, 0.0, 0.0)).collect();
        let mut map = MapCloud { frame_id: "map".into(), points };
        let limits = InputLimits { max_map_points: 4, ..Default::default() };
        assert_eq!(limit_map(&mut map, &limits), 6);
        let xs: Vec<f32> = map.points.iter().map(|p| p.x).collect();
        assert_eq!(xs, vec![0.0, 3.0, 5.0, 8.0]);
    }

    #[test]
    fn image_side_limit_names_the_size() {
        let limits = InputLimits::default();
        assert!(check_image_side("CameraInfo", 640, 480, &limits).is_ok());
        let err = check_image_side("CameraInfo", 4_000_000_000, 1, &limits).unwrap_err();
        assert!(err.contains("4000000000x1") && err.contains("8192"), "{err}");
    }

    #[test]
    fn image_pixel_limit_names_the_limit_and_the_size() {
        let limits = InputLimits::default();
        assert!(check_image_size("image", 4096, 4096, &limits).is_ok());
        let err = check_image_size("image", 8192, 8192, &limits).unwrap_err();
        assert!(err.contains("limits.max_image_pixels = 16777216") && err.contains("8192x8192"), "{err}");
        assert!(err.contains("67108864 pixels"), "{err}");
        let err = check_image_size("image", 8193, 1, &limits).unwrap_err();
        assert!(err.contains("limits.max_image_side"), "the side is checked first: {err}");
        let err = check_image_pixels("image", u32::MAX, u32::MAX, &limits).unwrap_err();
        assert!(err.contains("18446744065119617025 pixels"), "no overflow: {err}");
    }
}

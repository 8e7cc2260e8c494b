//! `eval --report DIR`: pictures and a page for every evaluation, so a run is looked at, not read.
//!
//! Written into DIR, for the input bag and each output bag scored:
//!
//! * `trajectory.png|svg` — the camera path seen from above: ground truth, each method's
//!   estimates, the frames it failed marked, the map points faint ([`trajectory`]);
//! * `cumulative.png|svg` — cumulative rotation, translation and RMSE error curves, with the RR
//!   threshold on the RMSE panel ([`cumulative`]);
//! * `frames-<method>.png|svg` — per frame over the run: time by stage, kept vs inlier counts,
//!   the prior's quality when the diagnostics carry `prior_quality`, and the outcome with the
//!   failure reasons ([`timeline`]);
//! * `frames-<method>-sheet.png` — the debug images (kept green, rejected red, true inliers
//!   ringed) of the worst and best frames ([`contact`]);
//! * `index.html` — all of it with the eval table and the failure list, readable offline
//!   ([`html`]).
//!
//! Text is drawn with Liberation Sans (SIL OFL 1.1, `LiberationSans-OFL.txt`), compiled in, so a
//! machine without fonts draws the same labels.

mod contact;
mod cumulative;
mod data;
mod figure;
mod html;
mod timeline;
mod trajectory;

use std::path::{Path, PathBuf};

use crate::app::Evaluation;
use crate::bag::{BagFrames, TopicMap};
use crate::eval::Summary;

pub use data::{read_run_records, FrameRecord, RunRecords};

/// Why a report could not be written.
#[derive(Debug, thiserror::Error)]
pub enum ReportError {
    #[error("{path}: {source}")]
    Io { path: PathBuf, source: std::io::Error },
    #[error("drawing {figure}: {message}")]
    Draw { figure: String, message: String },
    #[error("encoding {path}: {message}")]
    Encode { path: PathBuf, message: String },
    #[error("{path}: {message}")]
    ReadRun { path: PathBuf, message: String },
    #[error("the input bag has no frame with ground truth to report on")]
    NoFrames,
    #[error("the font compiled into the report cannot be loaded")]
    Font,
}

/// One output bag as evaluated: its table label, where it is, and the scores per frame.
pub struct MethodRun<'a> {
    pub label: String,
    pub est: PathBuf,
    pub evaluation: &'a Evaluation,
}

/// Everything the report shows.
pub struct ReportInput<'a> {
    /// The input bag's path (the page's title).
    pub bag_path: &'a Path,
    pub bag: &'a BagFrames,
    pub topics: &'a TopicMap,
    /// The matcher's raw correspondences, scored.
    pub raw: &'a Summary,
    pub runs: Vec<MethodRun<'a>>,
}

/// The files a report consists of, relative to its directory; `index.html` first.
#[derive(Debug, Default)]
pub struct ReportFiles {
    pub files: Vec<String>,
}

/// Writes the report for `input` into `dir` (created if missing; files of an earlier report
/// there are replaced).
pub fn write_report(input: &ReportInput, dir: &Path) -> Result<ReportFiles, ReportError> {
    figure::register_font()?;
    std::fs::create_dir_all(dir).map_err(|source| ReportError::Io { path: dir.to_path_buf(), source })?;
    let scored = data::ScoredRuns::build(input)?;
    let mut written = Vec::new();
    let trajectory = trajectory::Trajectory::new(input.bag, &scored);
    written.extend(figure::write_png_and_svg(&trajectory, dir, "trajectory")?);
    let cumulative = cumulative::CumulativeErrors::new(&scored);
    written.extend(figure::write_png_and_svg(&cumulative, dir, "cumulative")?);
    let mut pages = Vec::new();
    for (index, run) in scored.runs.iter().enumerate() {
        let stem = format!("frames-{}", file_safe(&run.label, index));
        let timeline = timeline::Timeline::new(run, index);
        written.extend(figure::write_png_and_svg(&timeline, dir, &stem)?);
        let sheet_name = format!("{stem}-sheet.png");
        let sheet = contact::contact_sheet(input.bag, run, index)?;
        figure::save_png(&sheet, &dir.join(&sheet_name), figure::Compression::Fast)?;
        written.push(sheet_name.clone());
        pages.push(html::RunFiles {
            timeline: format!("{stem}.png"),
            timeline_svg: format!("{stem}.svg"),
            sheet: sheet_name,
        });
    }
    let index_html = html::page(input, &scored, &pages);
    let index_path = dir.join("index.html");
    std::fs::write(&index_path, index_html).map_err(|source| ReportError::Io { path: index_path, source })?;
    written.insert(0, "index.html".to_string());
    Ok(ReportFiles { files: written })
}

/// `label` as a file-name part: letters, digits, `-` and `_` kept, the rest `_`; the run's
/// index is appended when the result is empty or would collide with another run's.
fn file_safe(label: &str, index: usize) -> String {
    let cleaned: String =
        label.chars().map(|c| if c.is_ascii_alphanumeric() || c == '-' || c == '_' { c } else { '_' }).collect();
    let trimmed = cleaned.trim_matches('_');
    if trimmed.is_empty() || trimmed != label {
        format!("{}{}", if trimmed.is_empty() { "run" } else { trimmed }, index + 1)
    } else {
        trimmed.to_string()
    }
}

#[cfg(test)]
mod tests {
    use super::file_safe;

    #[test]
    fn file_names_are_safe_and_distinct() {
        assert_eq!(file_safe("angle-i2p", 0), "angle-i2p");
        assert_eq!(file_safe("ransac (out/a b)", 2), "ransac__out_a_b3");
        assert_eq!(file_safe("ransac (out/a_c)", 3), "ransac__out_a_c4");
        assert_eq!(file_safe("../..", 0), "run1");
    }
}

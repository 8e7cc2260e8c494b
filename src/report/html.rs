//! `index.html`: the eval table, the figures, and every failure, on one page that needs nothing
//! but the files beside it (inline style, no script, relative links).

use std::fmt::Write;

use super::data::{Outcome, ScoredRuns};
use super::figure::method_colour;
use super::ReportInput;
use crate::eval::Summary;

/// The files of one method's section.
pub struct RunFiles {
    pub timeline: String,
    pub timeline_svg: String,
    pub sheet: String,
}

const STYLE: &str = "body{font-family:sans-serif;max-width:1400px;margin:1em auto;padding:0 1em;color:#222}\
table{border-collapse:collapse;margin:0.5em 0}td,th{border:1px solid #bbb;padding:3px 8px;text-align:right}\
th:first-child,td:first-child{text-align:left}\
.failures td:last-child{text-align:left}img{max-width:100%;border:1px solid #ddd}\
.swatch{display:inline-block;width:0.9em;height:0.9em;margin-right:0.4em;vertical-align:middle}\
details{margin:0.5em 0}figure{margin:1em 0}figcaption{color:#555;font-size:0.9em}";

/// Text safe inside HTML elements and attribute values.
pub fn escape(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    for c in text.chars() {
        match c {
            '&' => out.push_str("&amp;"),
            '<' => out.push_str("&lt;"),
            '>' => out.push_str("&gt;"),
            '"' => out.push_str("&quot;"),
            '\'' => out.push_str("&#39;"),
            _ => out.push(c),
        }
    }
    out
}

pub fn page(input: &ReportInput, scored: &ScoredRuns, files: &[RunFiles]) -> String {
    let bag = escape(&input.bag_path.display().to_string());
    let mut html = format!(
        "<!DOCTYPE html>\n<html lang=\"en\"><head><meta charset=\"utf-8\"><title>angle-i2p eval: {bag}</title>\
         <style>{STYLE}</style></head><body>\n<h1>angle-i2p eval: {bag}</h1>\n"
    );
    html += &table(input.raw, scored);
    html += "<p>IR: share of kept correspondences that are true inliers (5 cm); RR: share of frames with RMSE \
             &lt; 0.1 m; MRE/MTE: mean rotation/translation error over frames with a pose; ms/frame: median \
             (mean) from /diagnostics.</p>\n";
    figure(
        &mut html,
        "trajectory.png",
        "trajectory.svg",
        "Trajectory from above: ground truth (black), each \
        method's estimates (filled: registered; hollow, tied to the truth: RMSE over 0.1 m; cross at the true \
        position: no pose), map points faint.",
    );
    figure(
        &mut html,
        "cumulative.png",
        "cumulative.svg",
        "Cumulative errors over all frames (a frame without a \
        pose is never within a bound); the RMSE panel marks the RR threshold, where each curve's height is its RR.",
    );
    for ((run, f), index) in scored.runs.iter().zip(files).zip(0..) {
        let colour = method_colour(index);
        let _ = writeln!(
            html,
            "<h2><span class=\"swatch\" style=\"background:rgb({},{},{})\"></span>{}</h2>",
            colour.0,
            colour.1,
            colour.2,
            escape(&run.label)
        );
        figure(
            &mut html,
            &f.timeline,
            &f.timeline_svg,
            "Per frame: time by stage (stacked), kept vs inlier counts, \
            prior quality when the run reports it, and each frame's outcome with failure reasons by kind.",
        );
        figure(
            &mut html,
            &f.sheet,
            &f.sheet,
            "Worst and best frames: kept correspondences green, rejected red, \
            true inliers (ground truth) ringed blue.",
        );
        html += &failures(run);
    }
    html += "</body></html>\n";
    html
}

fn figure(html: &mut String, src: &str, link: &str, caption: &str) {
    let (src, link) = (escape(src), escape(link));
    let _ = writeln!(
        html,
        "<figure><a href=\"{link}\"><img src=\"{src}\" alt=\"{src}\"></a><figcaption>{}</figcaption></figure>",
        escape(caption)
    );
}

fn table(raw: &Summary, scored: &ScoredRuns) -> String {
    let opt = |v: Option<f64>, p: usize| v.map_or_else(|| "–".to_string(), |x| format!("{x:.p$}"));
    let mut out = String::from(
        "<table><tr><th>method</th><th>frames</th><th>IR %</th><th>RR %</th><th>available %</th>\
         <th>false poses %</th><th>MRE °</th><th>MTE m</th><th>MedRE °</th><th>MedTE m</th><th>ms/frame</th>\
         <th>in 95 % ellipsoid %</th><th>median NEES</th></tr>\n",
    );
    let _ = writeln!(
        out,
        "<tr><td>raw matches (IR only)</td><td>{}</td><td>{:.2}</td><td>–</td><td>–</td><td>–</td><td>–</td>\
         <td>–</td><td>–</td><td>–</td><td>–</td></tr>",
        raw.frames, raw.ir
    );
    for (index, run) in scored.runs.iter().enumerate() {
        let s = &run.summary;
        let c = method_colour(index);
        let ms = match (s.median_ms, s.ms_per_frame) {
            (Some(med), Some(mean)) => format!("{med:.2} ({mean:.2})"),
            _ => "–".into(),
        };
        let _ = writeln!(
            out,
            "<tr><td><span class=\"swatch\" style=\"background:rgb({},{},{})\"></span>{}</td><td>{}</td>\
             <td>{:.2}</td><td>{:.2}</td><td>{:.1}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td><td>{}</td>\
             <td>{}</td><td>{}</td><td>{}</td></tr>",
            c.0,
            c.1,
            c.2,
            escape(&run.label),
            s.frames,
            s.ir,
            s.rr,
            s.availability,
            opt(s.false_pose_rate, 1),
            opt(s.mre, 3),
            opt(s.mte, 3),
            opt(s.med_re, 3),
            opt(s.med_te, 3),
            ms,
            opt(s.covariance_95, 1),
            opt(s.median_nees, 1)
        );
    }
    out + "</table>\n"
}

/// Every frame the method did not register, with its errors or failure reason.
fn failures(run: &super::data::ScoredRun) -> String {
    let missed: Vec<_> = run.frames.iter().filter(|f| f.outcome() != Outcome::Registered).collect();
    let mut out = format!(
        "<details{}><summary>{} of {} frames not registered{}</summary>\n",
        if missed.len() <= 20 { " open" } else { "" },
        missed.len(),
        run.frames.len(),
        if run.unscored_failures.is_empty() {
            String::new()
        } else {
            format!("; {} more skipped before localization", run.unscored_failures.len())
        }
    );
    if !missed.is_empty() || !run.unscored_failures.is_empty() {
        out += "<table class=\"failures\"><tr><th>frame</th><th>stamp (ns)</th><th>outcome</th></tr>\n";
        for f in missed {
            let what = match (f.metrics.errors, &f.record.failure) {
                (Some(e), _) => format!("RMSE {:.3} m, {:.2}°, {:.3} m", e.rmse_m, e.rotation_deg, e.translation_m),
                (None, Some(reason)) => format!("no pose: {reason}"),
                (None, None) => "no pose in the output bag".to_string(),
            };
            let _ = writeln!(
                out,
                "<tr><td>{}</td><td>{}</td><td>{}</td></tr>",
                f.frame_index,
                f.metrics.stamp,
                escape(&what)
            );
        }
        for (stamp, reason) in &run.unscored_failures {
            let _ = writeln!(out, "<tr><td>–</td><td>{stamp}</td><td>{}</td></tr>", escape(reason));
        }
        out += "</table>\n";
    }
    out + "</details>\n"
}

#[cfg(test)]
mod tests {
    use super::escape;

    #[test]
    fn text_is_escaped() {
        assert_eq!(escape("a<b & \"c\" 'd'>"), "a&lt;b &amp; &quot;c&quot; &#39;d&#39;&gt;");
    }
}

//! `eval --report DIR` on a shipped bag: every picture is there, decodes and shows something,
//! the page holds the eval table and links only files that exist.

mod common;

use std::collections::BTreeSet;
use std::path::Path;
use std::process::Command;

use common::{binary, manifest, onnx_runtime, run_ok};

/// Methods to report on: the two that need no ONNX Runtime, and the default one when it is there.
fn methods() -> Vec<&'static str> {
    let mut m = vec!["ransac", "consistency"];
    if onnx_runtime().is_some() {
        m.push("angle-i2p");
    }
    m
}

/// Every `src="…"` and `href="…"` of the page.
fn references(html: &str) -> BTreeSet<String> {
    let mut refs = BTreeSet::new();
    for attr in ["src=\"", "href=\""] {
        for (at, _) in html.match_indices(attr) {
            let rest = &html[at + attr.len()..];
            if let Some(end) = rest.find('"') {
                refs.insert(rest[..end].to_string());
            }
        }
    }
    refs
}

/// Asserts the PNG at `path` decodes and is not blank: many colours, a real share of non-white.
fn assert_picture(path: &Path) -> image::RgbImage {
    let img = image::open(path).unwrap_or_else(|e| panic!("{}: {e}", path.display())).to_rgb8();
    let (w, h) = img.dimensions();
    assert!(w >= 300 && h >= 200, "{}: only {w}×{h}", path.display());
    let colours: BTreeSet<[u8; 3]> = img.pixels().map(|p| p.0).collect();
    assert!(colours.len() > 50, "{}: {} colours", path.display(), colours.len());
    let inked = img.pixels().filter(|p| p.0 != [255, 255, 255]).count();
    assert!(inked * 50 > (w * h) as usize, "{}: {inked} of {} pixels drawn", path.display(), w * h);
    img
}

fn count_colour(img: &image::RgbImage, rgb: [u8; 3]) -> usize {
    img.pixels().filter(|p| p.0 == rgb).count()
}

#[test]
fn report_for_a_shipped_bag() {
    let bag = manifest().join("bags/synth-hard");
    let dir = tempfile::tempdir().unwrap();
    let methods = methods();
    let mut eval = Command::new(binary());
    eval.arg("eval").arg(&bag);
    for m in &methods {
        let out = dir.path().join(format!("out-{m}"));
        run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out).args(["--method", m]));
        eval.arg("--est").arg(&out);
    }
    let report = dir.path().join("report");
    let json = run_ok(eval.arg("--json").arg("--report").arg(&report));
    let scores: serde_json::Value = serde_json::from_str(&json).unwrap();

    let html = std::fs::read_to_string(report.join("index.html")).unwrap();
    let refs = references(&html);
    for r in &refs {
        assert!(!r.contains(':') && !r.starts_with('/') && !r.contains(".."), "not a local relative link: {r}");
        assert!(report.join(r).is_file(), "index.html links {r}, which is missing");
    }
    let mut expected = vec!["trajectory.png".to_string(), "cumulative.png".to_string()];
    for m in &methods {
        expected.push(format!("frames-{m}.png"));
        expected.push(format!("frames-{m}-sheet.png"));
        // The table row: the label and the RR eval computed.
        let rr = scores[m]["RR"].as_f64().unwrap_or_else(|| panic!("no RR for {m} in {json}"));
        let row =
            html.lines().find(|l| l.contains(&format!("</span>{m}</td>"))).unwrap_or_else(|| panic!("no row {m}"));
        assert!(row.contains(&format!("<td>{rr:.2}</td>")), "RR {rr:.2} not in {row}");
    }
    for name in &expected {
        assert!(refs.contains(name), "index.html does not show {name}");
        let img = assert_picture(&report.join(name));
        if name.ends_with("-sheet.png") {
            // The debug drawing: kept green, rejected red, true inliers ringed.
            let kept = count_colour(&img, angle_i2p::node::image::KEPT);
            let rejected = count_colour(&img, angle_i2p::node::image::REJECTED);
            assert!(kept > 500 && rejected > 500, "{name}: {kept} kept, {rejected} rejected pixels");
        }
    }
    for svg in refs.iter().filter(|r| r.ends_with(".svg")) {
        let text = std::fs::read_to_string(report.join(svg)).unwrap();
        assert!(text.starts_with("<svg") && text.trim_end().ends_with("</svg>"), "{svg} is not an SVG document");
        assert!(text.contains("<text"), "{svg} has no labels");
    }
    // Every PNG written is on the page.
    for entry in std::fs::read_dir(&report).unwrap() {
        let name = entry.unwrap().file_name().to_string_lossy().into_owned();
        assert!(name == "index.html" || refs.contains(&name), "{name} is written but not shown");
    }
}

#[test]
fn report_into_a_file_is_an_error_naming_it() {
    let bag = manifest().join("bags/synth-hard");
    let dir = tempfile::tempdir().unwrap();
    let out = dir.path().join("out");
    run_ok(Command::new(binary()).arg("replay").arg(&bag).arg("--out").arg(&out).args(["--method", "consistency"]));
    let blocker = dir.path().join("not-a-dir");
    std::fs::write(&blocker, b"x").unwrap();
    let result = Command::new(binary())
        .arg("eval")
        .arg(&bag)
        .arg("--est")
        .arg(&out)
        .arg("--report")
        .arg(&blocker)
        .output()
        .unwrap();
    assert!(!result.status.success());
    let stderr = String::from_utf8_lossy(&result.stderr);
    assert!(stderr.contains("not-a-dir") && stderr.contains("report"), "{stderr}");
}

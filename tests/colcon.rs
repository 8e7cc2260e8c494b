//! The repository as ROS 2 packages: `colcon build` of the Rust package in a scratch workspace
//! (colcon-ros-cargo + cargo-ament-build from `make colcon-venv`), what it installs, the launch
//! files' references, and the message package against the rosidl tutorial's layout (rosidl
//! itself needs a ROS installation and is not installable here, so that package is checked,
//! not built).

mod common;

use std::path::{Path, PathBuf};
use std::process::Command;

use common::{binary, manifest, run_ok, skip_or_fail};

/// `.venv-colcon/bin` when `make colcon-venv` made it.
fn colcon_bin() -> Option<PathBuf> {
    let bin = manifest().join(".venv-colcon/bin");
    if bin.join("colcon").exists() && bin.join("cargo-ament-build").exists() {
        return Some(bin);
    }
    skip_or_fail("colcon / cargo-ament-build missing (make colcon-venv)");
    None
}

fn colcon(bin: &Path, ws: &Path) -> Command {
    let path = std::env::var_os("PATH").unwrap_or_default();
    let mut paths = vec![bin.to_path_buf()];
    paths.extend(std::env::split_paths(&path));
    let mut cmd = Command::new(bin.join("colcon"));
    cmd.current_dir(ws).env("PATH", std::env::join_paths(paths).expect("PATH"));
    cmd
}

/// Every `$(find-pkg-share angle_i2p)/…` path and every node's `pkg`/`exec` in a launch file.
fn launch_references(doc: &serde_yaml::Value, shares: &mut Vec<String>, nodes: &mut Vec<(String, String)>) {
    match doc {
        serde_yaml::Value::Mapping(m) => {
            if let (Some(pkg), Some(exec)) = (m.get("pkg"), m.get("exec")) {
                nodes.push((
                    pkg.as_str().unwrap_or_default().to_string(),
                    exec.as_str().unwrap_or_default().to_string(),
                ));
            }
            m.values().for_each(|v| launch_references(v, shares, nodes));
        }
        serde_yaml::Value::Sequence(s) => s.iter().for_each(|v| launch_references(v, shares, nodes)),
        serde_yaml::Value::String(s) => {
            if let Some(rest) = s.split("$(find-pkg-share angle_i2p)/").nth(1) {
                shares.push(rest.to_string());
            }
        }
        _ => {}
    }
}

/// `colcon build` of the Rust package in a scratch workspace, reusing this test run's build
/// (the profile directory is linked into colcon's build base, so nothing is compiled again):
/// the ament index has `angle_i2p`, the executable runs, the share directory has the launch
/// files, params and model, and every installed launch file names an executable and share files
/// that exist. Both packages are discovered (the message package through its own base path).
#[test]
fn colcon_builds_and_installs_the_rust_package() {
    let Some(bin) = colcon_bin() else { return };
    let tmp = tempfile::tempdir().expect("tmp");
    let ws = tmp.path();
    std::fs::create_dir_all(ws.join("src")).expect("src");
    std::os::unix::fs::symlink(manifest(), ws.join("src/angle-i2p")).expect("link the repo");
    let profile_dir = binary().parent().expect("profile dir").to_path_buf();
    let profile = profile_dir.file_name().and_then(|n| n.to_str()).expect("profile").to_string();
    std::fs::create_dir_all(ws.join("build/angle_i2p")).expect("build base");
    std::os::unix::fs::symlink(&profile_dir, ws.join("build/angle_i2p").join(&profile)).expect("link the build");

    let listed =
        run_ok(colcon(&bin, ws).args(["list", "--base-paths", "src/angle-i2p", "src/angle-i2p/angle_i2p_msgs"]));
    assert!(listed.lines().any(|l| l.starts_with("angle_i2p\t") && l.ends_with("(ament_cargo)")), "{listed}");
    assert!(listed.lines().any(|l| l.starts_with("angle_i2p_msgs\t") && l.contains("ament_cmake")), "{listed}");

    let mut build = colcon(&bin, ws);
    build.args(["build", "--base-paths", "src/angle-i2p", "--packages-select", "angle_i2p"]);
    if profile == "release" {
        build.args(["--cargo-args", "--release"]);
    }
    run_ok(&mut build);

    let prefix = ws.join("install/angle_i2p");
    let share = prefix.join("share/angle_i2p");
    let lib = prefix.join("lib/angle_i2p");
    assert!(prefix.join("share/ament_index/resource_index/packages/angle_i2p").exists(), "not in the ament index");
    for f in ["package.xml", "params/angle_i2p.yaml", "params/expert.yaml", "models/angle_i2p.onnx"] {
        assert!(share.join(f).exists(), "share/angle_i2p/{f} not installed");
    }
    let params = run_ok(Command::new(lib.join("angle-i2p")).args(["params"]).current_dir(ws));
    assert!(params.contains("ros__parameters"), "{params}");

    let mut launch_files = 0;
    for entry in std::fs::read_dir(share.join("launch_configs")).expect("launch_configs installed") {
        let path = entry.expect("entry").path();
        if !path.to_string_lossy().ends_with(".launch.yaml") {
            continue;
        }
        let text = std::fs::read_to_string(&path).expect("launch file");
        let doc: serde_yaml::Value = serde_yaml::from_str(&text).expect("launch YAML");
        let (mut shares, mut nodes) = (Vec::new(), Vec::new());
        launch_references(&doc, &mut shares, &mut nodes);
        let ours: Vec<_> = nodes.iter().filter(|(pkg, _)| pkg == "angle_i2p").collect();
        assert!(!ours.is_empty(), "{}: no angle_i2p node", path.display());
        for (_, exec) in ours {
            assert!(lib.join(exec).exists(), "{}: exec {exec} is not in lib/angle_i2p", path.display());
        }
        for rel in shares {
            assert!(share.join(&rel).exists(), "{}: $(find-pkg-share angle_i2p)/{rel} missing", path.display());
        }
        launch_files += 1;
    }
    assert!(launch_files >= 2, "launch files installed: {launch_files}");
}

/// The message package as the rosidl tutorial lays one out: every `.msg` listed in
/// `rosidl_generate_interfaces`, the generator as build tool, the runtime as exec dependency,
/// membership of `rosidl_interface_packages`; and the Rust package's manifest names match.
#[test]
fn packages_are_laid_out_as_ros_expects() {
    let msgs = manifest().join("angle_i2p_msgs");
    let cmake = std::fs::read_to_string(msgs.join("CMakeLists.txt")).expect("CMakeLists.txt");
    let xml = std::fs::read_to_string(msgs.join("package.xml")).expect("package.xml");
    assert!(cmake.contains("project(angle_i2p_msgs)"));
    assert!(cmake.contains("find_package(rosidl_default_generators REQUIRED)"));
    assert!(cmake.contains("ament_export_dependencies(rosidl_default_runtime)"));
    let mut count = 0;
    for entry in std::fs::read_dir(msgs.join("msg")).expect("msg/") {
        let name = entry.expect("entry").file_name().to_string_lossy().to_string();
        if name.ends_with(".msg") {
            assert!(cmake.contains(&format!("\"msg/{name}\"")), "{name} not in rosidl_generate_interfaces");
            count += 1;
        }
    }
    assert_eq!(count, 2);
    for needle in [
        "<name>angle_i2p_msgs</name>",
        "<buildtool_depend>rosidl_default_generators</buildtool_depend>",
        "<exec_depend>rosidl_default_runtime</exec_depend>",
        "<member_of_group>rosidl_interface_packages</member_of_group>",
        "<build_type>ament_cmake</build_type>",
    ] {
        assert!(xml.contains(needle), "angle_i2p_msgs/package.xml lacks {needle}");
    }
    let cargo: toml_like::Manifest = toml_like::read(&manifest().join("Cargo.toml"));
    let root_xml = std::fs::read_to_string(manifest().join("package.xml")).expect("package.xml");
    assert!(root_xml.contains(&format!("<name>{}</name>", cargo.package_name)), "Cargo and ROS package names differ");
    assert!(root_xml.contains("<build_type>ament_cargo</build_type>"));
    assert_eq!(binary().file_name().and_then(|n| n.to_str()), Some("angle-i2p"));
}

/// The two lines of Cargo.toml this test needs (no TOML parser among the dependencies).
mod toml_like {
    use std::path::Path;

    pub struct Manifest {
        pub package_name: String,
    }

    pub fn read(path: &Path) -> Manifest {
        let text = std::fs::read_to_string(path).expect("Cargo.toml");
        let package = text.split("[package]").nth(1).expect("[package]");
        let name = package
            .lines()
            .find_map(|l| l.trim().strip_prefix("name = "))
            .map(|v| v.trim_matches('"').to_string())
            .expect("package name");
        Manifest { package_name: name }
    }
}

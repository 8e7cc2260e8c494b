//! Files of an installed node (`colcon build`: cargo-ament-build puts the binary in
//! `<prefix>/lib/angle_i2p/` and `install_to_share` the model and params in
//! `<prefix>/share/angle_i2p/`): a relative model path is looked up in the package's share
//! directory, and ONNX Runtime in its lib directory, before the working directory and the
//! source tree the binary was built from ([`crate::reject::network::locate`]).

use std::path::{Path, PathBuf};

use crate::params::LocalizerParams;
use crate::reject::network::ONNXRUNTIME_LIBRARY;

/// The ROS package name.
pub const PACKAGE: &str = "angle_i2p";

/// The install layout around an installed binary.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct InstallDirs {
    /// `<prefix>/share/angle_i2p`.
    pub share: PathBuf,
    /// `<prefix>/lib/angle_i2p`.
    pub lib: PathBuf,
}

impl InstallDirs {
    /// The layout when `exe` is `<prefix>/lib/angle_i2p/<binary>`; `None` otherwise (a cargo build).
    pub fn of_binary(exe: &Path) -> Option<Self> {
        let lib = exe.parent()?;
        if lib.file_name()? != PACKAGE || lib.parent()?.file_name()? != "lib" {
            return None;
        }
        let prefix = lib.parent()?.parent()?;
        Some(Self { share: prefix.join("share").join(PACKAGE), lib: lib.to_path_buf() })
    }

    /// Points relative model and runtime paths at the installed files when those exist and the
    /// paths as given do not resolve from the working directory. Returns what it changed.
    pub fn resolve(&self, params: &mut LocalizerParams) -> Vec<String> {
        let mut changed = Vec::new();
        let net = &mut params.network;
        let model = Path::new(&net.model_path);
        if model.is_relative() && !model.exists() {
            let installed = self.share.join(model);
            if installed.exists() {
                changed.push(format!("network.model_path {}", installed.display()));
                net.model_path = installed.display().to_string();
            }
        }
        if net.onnxruntime_path.is_empty() && std::env::var_os("ORT_DYLIB_PATH").is_none() {
            let installed = self.lib.join(ONNXRUNTIME_LIBRARY);
            if installed.exists() && !Path::new(".ort").join(ONNXRUNTIME_LIBRARY).exists() {
                changed.push(format!("network.onnxruntime_path {}", installed.display()));
                net.onnxruntime_path = installed.display().to_string();
            }
        }
        changed
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn installed_layout_resolves_the_model_from_share() {
        assert_eq!(InstallDirs::of_binary(Path::new("/repo/target/release/angle-i2p")), None);
        let tmp = tempfile::tempdir().unwrap();
        let prefix = tmp.path().join("install/angle_i2p");
        let dirs = InstallDirs::of_binary(&prefix.join("lib/angle_i2p/angle-i2p")).expect("installed layout");
        assert_eq!(dirs.share, prefix.join("share/angle_i2p"));
        std::fs::create_dir_all(dirs.share.join("models")).unwrap();
        std::fs::write(dirs.share.join("models/test-only.onnx"), b"x").unwrap();
        let mut p = LocalizerParams::default();
        p.network.model_path = "models/test-only.onnx".into();
        let changed = dirs.resolve(&mut p);
        assert_eq!(p.network.model_path, dirs.share.join("models/test-only.onnx").display().to_string());
        assert_eq!(changed.len(), 1, "{changed:?}");
        // Absolute paths and files that resolve as given are left alone.
        let mut p = LocalizerParams::default();
        p.network.model_path = "/elsewhere/m.onnx".into();
        assert!(dirs.resolve(&mut p).is_empty());
        assert_eq!(p.network.model_path, "/elsewhere/m.onnx");
    }
}

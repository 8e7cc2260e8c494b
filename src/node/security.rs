//! SROS2, read as rcl reads it (`ROS_SECURITY_ENABLE`, `ROS_SECURITY_STRATEGY`,
//! `ROS_SECURITY_KEYSTORE`, `ROS_SECURITY_ENCLAVE_OVERRIDE`, `--enclave`): with security on, the
//! enclave's files in an SROS2 keystore (`<keystore>/enclaves/<enclave>/`, as `ros2 security
//! create_enclave` or `scripts/make_test_keystore.sh` lays them out) secure the DDS participant
//! (authentication, access control and encryption: RustDDS's built-in plugins). Enforce mode
//! refuses to start without them, with the reason; Permissive mode runs unsecured and says so,
//! as rcl does.

use std::path::{Path, PathBuf};

/// The files of an enclave, as SROS2 names them (and RustDDS reads them).
pub const ENCLAVE_FILES: [&str; 6] =
    ["cert.pem", "key.pem", "governance.p7s", "permissions.p7s", "identity_ca.cert.pem", "permissions_ca.cert.pem"];

/// What the security environment asks of a participant.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SecurityPlan {
    /// Security is off (`ROS_SECURITY_ENABLE` is not `true`); an `--enclave` is noted only.
    Off { enclave: Option<String> },
    /// Security is on in Permissive mode without a usable enclave: unsecured, and said why.
    Unsecured { enclave: String, why: String },
    /// Secured with the enclave's files in `dir`.
    Secured { enclave: String, dir: PathBuf },
}

/// Why a participant may not start under the security environment.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SecurityError {
    #[error(
        "ROS_SECURITY_ENABLE=true with ROS_SECURITY_STRATEGY=Enforce, but enclave {enclave:?} is unusable: {why}; \
         refusing to start unsecured (ROS_SECURITY_STRATEGY=Permissive runs unsecured knowingly)"
    )]
    Enforced { enclave: String, why: String },
}

/// The security environment: the variables' values (`None`: unset) and `--enclave`.
#[derive(Clone, Debug, Default)]
pub struct SecurityEnv {
    pub enable: Option<String>,
    pub strategy: Option<String>,
    pub keystore: Option<String>,
    pub enclave_override: Option<String>,
    pub enclave_arg: Option<String>,
}

impl SecurityEnv {
    /// From the process environment and the `--enclave` argument.
    pub fn from_process(enclave_arg: Option<&str>) -> Self {
        // rcl reads an empty variable as unset.
        let var = |name: &str| std::env::var(name).ok().filter(|v| !v.is_empty());
        Self {
            enable: var("ROS_SECURITY_ENABLE"),
            strategy: var("ROS_SECURITY_STRATEGY"),
            keystore: var("ROS_SECURITY_KEYSTORE"),
            enclave_override: var("ROS_SECURITY_ENCLAVE_OVERRIDE"),
            enclave_arg: enclave_arg.map(str::to_string),
        }
    }

    /// What to do: rcl enables security only for `ROS_SECURITY_ENABLE=true` (exactly), and
    /// enforces only for `ROS_SECURITY_STRATEGY=Enforce` (exactly; anything else is Permissive).
    /// The enclave is the override when set, else `--enclave`, else `/`.
    pub fn plan(&self) -> Result<SecurityPlan, SecurityError> {
        let named = self.enclave_override.clone().or_else(|| self.enclave_arg.clone());
        if self.enable.as_deref() != Some("true") {
            return Ok(SecurityPlan::Off { enclave: named });
        }
        let enclave = named.unwrap_or_else(|| "/".into());
        match self.enclave_dir(&enclave) {
            Ok(dir) => Ok(SecurityPlan::Secured { enclave, dir }),
            Err(why) if self.strategy.as_deref() == Some("Enforce") => Err(SecurityError::Enforced { enclave, why }),
            Err(why) => Ok(SecurityPlan::Unsecured { enclave, why }),
        }
    }

    /// The enclave's directory in the keystore, holding every file of [`ENCLAVE_FILES`].
    fn enclave_dir(&self, enclave: &str) -> Result<PathBuf, String> {
        let keystore = self.keystore.as_deref().ok_or("ROS_SECURITY_KEYSTORE is not set")?;
        let dir = Path::new(keystore).join("enclaves").join(enclave.trim_start_matches('/'));
        let missing: Vec<&str> = ENCLAVE_FILES.into_iter().filter(|f| !dir.join(f).is_file()).collect();
        match missing.is_empty() {
            true => Ok(dir),
            false => Err(format!("{} lacks {}", dir.display(), missing.join(", "))),
        }
    }
}

impl SecurityPlan {
    /// The plan of this process (its environment and `--enclave` argument), its start line
    /// logged as `participant`: the node and `play` set up security the same way.
    pub fn for_process(enclave_arg: Option<&str>, participant: &str) -> Result<Self, SecurityError> {
        let plan = SecurityEnv::from_process(enclave_arg).plan()?;
        if let Some(line) = plan.describe() {
            eprintln!("[{participant}] {line}");
        }
        Ok(plan)
    }

    /// The line a participant logs at start for this plan (none when security is off and no
    /// enclave was named).
    pub fn describe(&self) -> Option<String> {
        match self {
            SecurityPlan::Off { enclave: Some(enclave) } => {
                Some(format!("enclave {enclave:?} noted; security is off (ROS_SECURITY_ENABLE is not true)"))
            }
            SecurityPlan::Off { enclave: None } => None,
            SecurityPlan::Unsecured { enclave, why } => Some(format!(
                "WARN ROS_SECURITY_ENABLE=true in Permissive mode, but enclave {enclave:?} is unusable ({why}): \
                 running UNSECURED"
            )),
            SecurityPlan::Secured { enclave, dir } => {
                Some(format!("secured (SROS2) as enclave {enclave:?} with {}", dir.display()))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(enable: Option<&str>, strategy: Option<&str>, keystore: &Path) -> SecurityEnv {
        SecurityEnv {
            enable: enable.map(str::to_string),
            strategy: strategy.map(str::to_string),
            keystore: Some(keystore.display().to_string()),
            enclave_override: None,
            enclave_arg: Some("/angle_i2p".into()),
        }
    }

    #[test]
    fn enforce_without_the_enclaves_files_refuses_to_start_and_says_why() {
        let keys = tempfile::tempdir().unwrap();
        let err = env(Some("true"), Some("Enforce"), keys.path()).plan().unwrap_err();
        let text = err.to_string();
        assert!(text.contains("Enforce") && text.contains("/angle_i2p") && text.contains("cert.pem"), "{text}");
        let mut no_keystore = env(Some("true"), Some("Enforce"), keys.path());
        no_keystore.keystore = None;
        assert!(no_keystore.plan().unwrap_err().to_string().contains("ROS_SECURITY_KEYSTORE"));
    }

    #[test]
    fn an_enclave_with_its_files_secures_the_participant() {
        let keys = tempfile::tempdir().unwrap();
        let dir = keys.path().join("enclaves/angle_i2p");
        std::fs::create_dir_all(&dir).unwrap();
        for f in ENCLAVE_FILES {
            std::fs::write(dir.join(f), "x").unwrap();
        }
        let plan = env(Some("true"), Some("Enforce"), keys.path()).plan().unwrap();
        assert_eq!(plan, SecurityPlan::Secured { enclave: "/angle_i2p".into(), dir: dir.clone() });
        std::fs::remove_file(dir.join("permissions.p7s")).unwrap();
        let SecurityPlan::Unsecured { why, .. } = env(Some("true"), None, keys.path()).plan().unwrap() else {
            panic!("Permissive runs unsecured")
        };
        assert!(why.contains("permissions.p7s"), "{why}");
    }

    #[test]
    fn permissive_or_off_runs_as_rcl_reads_the_variables() {
        let keys = tempfile::tempdir().unwrap();
        let enclave = Some("/angle_i2p".to_string());
        let unsecured = |plan: SecurityPlan| matches!(plan, SecurityPlan::Unsecured { .. });
        assert!(unsecured(env(Some("true"), None, keys.path()).plan().unwrap()));
        assert!(unsecured(env(Some("true"), Some("Permissive"), keys.path()).plan().unwrap()));
        // rcl compares exactly: `TRUE` or `1` leave security off, `enforce` is Permissive.
        let off = SecurityPlan::Off { enclave: enclave.clone() };
        assert_eq!(env(Some("TRUE"), Some("Enforce"), keys.path()).plan(), Ok(off.clone()));
        assert!(unsecured(env(Some("true"), Some("enforce"), keys.path()).plan().unwrap()));
        assert_eq!(env(None, Some("Enforce"), keys.path()).plan(), Ok(off));
        let mut overridden = env(None, None, keys.path());
        overridden.enclave_override = Some("/robot".into());
        assert_eq!(overridden.plan(), Ok(SecurityPlan::Off { enclave: Some("/robot".into()) }));
    }
}

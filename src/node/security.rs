//! SROS2's environment, read as rcl reads it (`ROS_SECURITY_ENABLE`, `ROS_SECURITY_STRATEGY`,
//! `ROS_SECURITY_KEYSTORE`, `--enclave`). DDS security is not built into this node yet (#37):
//! where rcl would run secured or refuse to start, this node must not run unsecured while the
//! operator believes otherwise. Enforce mode therefore refuses to start, with the reason;
//! Permissive mode, as rcl's with no usable keystore, runs unsecured and says so.

/// What the security environment asks of the node.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum SecurityPlan {
    /// Security is off (`ROS_SECURITY_ENABLE` is not `true`); an `--enclave` is noted only.
    Off { enclave: Option<String> },
    /// Security is on in Permissive mode: the node runs unsecured and warns.
    Unsecured { enclave: Option<String> },
}

/// Why the node may not start under the security environment.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum SecurityError {
    #[error(
        "ROS_SECURITY_ENABLE=true with ROS_SECURITY_STRATEGY=Enforce (keystore {keystore:?}, enclave {enclave:?}): \
         DDS security (SROS2) is not built into this node, which would run unsecured; refusing to start \
         (use ROS_SECURITY_STRATEGY=Permissive to run it unsecured knowingly)"
    )]
    EnforceUnsupported { keystore: Option<String>, enclave: Option<String> },
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
    /// The enclave is the override when set, else `--enclave`.
    pub fn plan(&self) -> Result<SecurityPlan, SecurityError> {
        let enclave = self.enclave_override.clone().or_else(|| self.enclave_arg.clone());
        if self.enable.as_deref() != Some("true") {
            return Ok(SecurityPlan::Off { enclave });
        }
        if self.strategy.as_deref() == Some("Enforce") {
            return Err(SecurityError::EnforceUnsupported { keystore: self.keystore.clone(), enclave });
        }
        Ok(SecurityPlan::Unsecured { enclave })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn env(enable: Option<&str>, strategy: Option<&str>) -> SecurityEnv {
        SecurityEnv {
            enable: enable.map(str::to_string),
            strategy: strategy.map(str::to_string),
            keystore: Some("/keys".into()),
            enclave_override: None,
            enclave_arg: Some("/angle_i2p".into()),
        }
    }

    #[test]
    fn enforce_refuses_to_start_and_says_why() {
        let err = env(Some("true"), Some("Enforce")).plan().unwrap_err();
        let text = err.to_string();
        assert!(text.contains("Enforce") && text.contains("/keys") && text.contains("/angle_i2p"), "{text}");
    }

    #[test]
    fn permissive_or_off_runs_as_rcl_reads_the_variables() {
        let enclave = Some("/angle_i2p".to_string());
        assert_eq!(env(Some("true"), None).plan(), Ok(SecurityPlan::Unsecured { enclave: enclave.clone() }));
        assert_eq!(
            env(Some("true"), Some("Permissive")).plan(),
            Ok(SecurityPlan::Unsecured { enclave: enclave.clone() })
        );
        // rcl compares exactly: `TRUE` or `1` leave security off, `enforce` is Permissive.
        assert_eq!(env(Some("TRUE"), Some("Enforce")).plan(), Ok(SecurityPlan::Off { enclave: enclave.clone() }));
        assert_eq!(env(Some("true"), Some("enforce")).plan(), Ok(SecurityPlan::Unsecured { enclave: enclave.clone() }));
        assert_eq!(env(None, Some("Enforce")).plan(), Ok(SecurityPlan::Off { enclave }));
        let mut overridden = env(None, None);
        overridden.enclave_override = Some("/robot".into());
        assert_eq!(overridden.plan(), Ok(SecurityPlan::Off { enclave: Some("/robot".into()) }));
    }
}

//! The node's life in named steps: parameters → the ROS node (parameter services, rosout,
//! `/clock`) → the lifecycle (its services; with `node.autostart`, configure and activate at
//! once) → the loop (lifecycle requests, and while configured: inputs, time-outs, diagnostics,
//! the `map → odom` re-send) → shutdown (the lifecycle's, on a signal or `~/change_state`). What
//! each lifecycle state holds is [`super::managed`]'s; what configure makes, [`super::configured`]'s.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use anyhow::Result;
use ros2_client::{Node, NodeOptions};

use super::clock;
use super::dds;
use super::lifecycle::State;
use super::lifecycle_services::ChangeRequest;
use super::log::{self, info, warn};
use super::managed::Managed;
use super::recorder::Recorder;
use super::ros_params::{self, LiveParams, LiveTargets};
use super::security::SecurityPlan;
use super::setup::Setup;
use crate::params::{AppParams, Names};

/// The node's options: every parameter declared with its resolved value, the parameter
/// services (writes checked and applied by `live`), rosout.
fn node_options(resolved: &AppParams, live: &LiveParams, rosout: bool) -> Result<NodeOptions> {
    let mut options = NodeOptions::new().enable_rosout(rosout).start_parameter_services(true);
    for p in ros_params::declared(resolved)? {
        options = options.declare_parameter(&p.name, p.value);
    }
    let (check, apply) = (live.clone(), live.clone());
    Ok(options
        .parameter_validator(Box::new(move |name, value| {
            check.check(name, value).map(|_| ()).map_err(|e| e.to_string())
        }))
        .parameter_set_action(Box::new(move |name, value| match apply.apply(name, value) {
            Ok(true) => {
                info(format!("parameter {name} set to {value:?}"));
                Ok(())
            }
            Ok(false) => Ok(()),
            Err(e) => Err(e.to_string()),
        })))
}

/// Runs the node until SIGINT/SIGTERM or a lifecycle shutdown; `record` also writes every
/// published message to a bag; `rosout`: log lines also go to `/rosout`; its DDS participant is
/// secured as `security` says.
pub async fn run_node(
    names: Names,
    resolved: AppParams,
    record: Option<PathBuf>,
    rosout: bool,
    security: &SecurityPlan,
) -> Result<()> {
    // 1. Parameters.
    let s = Setup::new(names, &resolved, record.as_deref())?;
    let live = LiveParams::new(
        resolved.clone(),
        LiveTargets {
            stats: s.cameras.iter().map(|c| c.stats.clone()).collect(),
            broadcast: s.cameras.iter().map(|c| c.broadcast.clone()).collect(),
            gate_width: s.gate_width.clone(),
            clock: s.clock.clone(),
        },
    );
    // 2. The ROS node: parameter services, rosout, `/clock` (`use_sim_time` may be switched on
    // in any state).
    let context = dds::context_for(security)?;
    let options = node_options(&resolved, &live, rosout)?;
    let mut node = dds::node_with_options(&context, &s.names.namespace, &s.names.node_name, options)?;
    if rosout {
        log::enable_rosout(node.logging_handle(), log::logger_name(&s.names.fully_qualified()));
    }
    let spinner = dds::spawn_spinner(&mut node)?;
    let _clock_reader = clock::subscribe(&mut node, &s.clock)?;
    // 3. The lifecycle: unconfigured, or configured and active at once (`node.autostart`).
    let mut managed = Managed::new(&context, &mut node, &s, live.clone())?;
    if s.np.autostart {
        managed.startup(&mut node, &s).await?;
    } else {
        info(format!(
            "node {} is unconfigured: waiting for ~/change_state (node.autostart is false)",
            s.names.fully_qualified()
        ));
    }
    // 4. The loop.
    run_loop(&s, &mut node, &mut managed).await;
    // 5. Shutdown.
    info("shutting down");
    if managed.current() != State::Finalized {
        managed.shutdown(&mut node, &s).await;
    }
    finish_recording(&s.recorder);
    node.stop_spinner();
    drop(node);
    // The spinner thread ends with the node; do not wait on it for long.
    let deadline = Instant::now() + Duration::from_secs(2);
    while !spinner.is_finished() && Instant::now() < deadline {
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
    Ok(())
}

/// What woke the loop that the loop itself must act on (the configured node's own wake-ups are
/// handled where they happen).
enum Wake {
    Handled,
    Signal,
    Change(Option<ChangeRequest>),
    ReadersGone,
}

/// Lifecycle requests, and while configured: inputs to the ingest, time-outs every 20 ms,
/// diagnostics every period, the `map → odom` re-send; until a signal, a lifecycle shutdown,
/// or every reader gone.
async fn run_loop(s: &Setup, node: &mut Node, managed: &mut Managed) {
    let mut tick = interval(Duration::from_millis(20));
    let mut diag_tick = interval(Duration::from_millis(s.np.diagnostics_period_ms.max(50)));
    // 0 Hz: no re-send (an interval that never fires in practice).
    let tf_period = if s.np.tf_publish_rate_hz > 0.0 {
        Duration::from_secs_f64((1.0 / s.np.tf_publish_rate_hz).max(1e-3))
    } else {
        Duration::from_secs(365 * 24 * 3600)
    };
    let mut tf_tick = interval(tf_period);
    let shutdown = shutdown_signal();
    futures::pin_mut!(shutdown);
    loop {
        let (requests, configured) = managed.parts();
        let wake = match configured {
            Some(c) => tokio::select! {
                _ = &mut shutdown => Wake::Signal,
                request = requests.recv() => Wake::Change(request),
                input = c.next_input() => match input {
                    Some(routed) => {
                        c.on_input(routed);
                        Wake::Handled
                    }
                    None => Wake::ReadersGone,
                },
                _ = tick.tick() => {
                    c.expire();
                    Wake::Handled
                }
                _ = diag_tick.tick() => {
                    c.publish_diagnostics(node, s).await;
                    Wake::Handled
                }
                _ = tf_tick.tick() => {
                    c.resend_tf(s).await;
                    Wake::Handled
                }
            },
            None => tokio::select! {
                _ = &mut shutdown => Wake::Signal,
                request = requests.recv() => Wake::Change(request),
            },
        };
        match wake {
            Wake::Handled => {}
            Wake::Signal | Wake::ReadersGone => break,
            Wake::Change(Some(request)) => {
                managed.on_request(request, node, s).await;
                if managed.current() == State::Finalized {
                    break;
                }
            }
            Wake::Change(None) => {
                warn("the lifecycle's ~/change_state server has ended: stopping");
                break;
            }
        }
    }
}

/// A tokio interval that skips the ticks it missed.
fn interval(period: Duration) -> tokio::time::Interval {
    let mut tick = tokio::time::interval(period);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Skip);
    tick
}

fn finish_recording(recorder: &Recorder) {
    match recorder.finish() {
        Some(Ok(p)) => info(format!("recorded to {}", p.display())),
        Some(Err(e)) => warn(format!("finishing the recording failed: {e:#}")),
        None => {}
    }
}

async fn shutdown_signal() {
    #[cfg(unix)]
    {
        use tokio::signal::unix::{signal, SignalKind};
        match signal(SignalKind::terminate()) {
            Ok(mut term) => {
                tokio::select! {
                    _ = tokio::signal::ctrl_c() => {}
                    _ = term.recv() => {}
                }
            }
            Err(_) => {
                let _ = tokio::signal::ctrl_c().await;
            }
        }
    }
    #[cfg(not(unix))]
    {
        let _ = tokio::signal::ctrl_c().await;
    }
}

//! The look-ahead planner set up on the bundled walk for the benches (`benches/control.rs`,
//! `benches/instructions.rs`): the CMU puppet's 28 servos at 500 Hz, a full preview ahead.

use std::sync::Arc;

use marionette::command::CommandStage;
use marionette::control::lookahead::{Lookahead, LookaheadSettings, Preview, SampleHead};
use marionette::control::sources::ClipPlayer;
use marionette::motion::Motion;
use marionette::profile::Profile;
use marionette::rig::{Rig, ServoMap};
use marionette::skeleton::{Skeleton, MAX_CHANNELS};

/// The planner, its command stage started at rest, and 200 samples of the walk (0.4 s) in the
/// preview, for `rig` driven by `profile`'s servos.
pub fn walk_planner(
    skel: &Arc<Skeleton>,
    motion: &Arc<Motion>,
    profile: &Profile,
    rig: &Rig,
) -> (Lookahead, CommandStage, Preview) {
    let present: Vec<i32> = rig.servos.iter().map(ServoMap::rest_tick).collect();
    let mut preview = Preview::new(256, rig.len(), skel.channel_count());
    let mut angles = vec![0.0; rig.len()];
    let mut player = ClipPlayer::new(Arc::clone(skel), Arc::clone(motion), 500.0, true);
    let mut buf = [0.0; MAX_CHANNELS];
    let n = skel.channel_count();
    for k in 0..200u64 {
        player.next_sample(&mut buf[..n]).unwrap();
        rig.joint_angles(skel, &buf[..n], &[], &mut angles);
        let head = SampleHead {
            due_ns: k * 2_000_000,
            ..SampleHead::default()
        };
        preview.push(head, &angles, &[], &buf[..n]);
    }
    preview.advance(1_000_000);
    preview.live = false;
    let leads: Vec<f64> = profile
        .servos
        .iter()
        .map(|s| s.lag_ms.unwrap_or(0.0) * 1e-3 + 0.002)
        .collect();
    let look = Lookahead::new(rig, 500.0, &leads, LookaheadSettings::default());
    let mut stage = CommandStage::new(rig.len());
    stage.start_from(rig, &present);
    (look, stage, preview)
}

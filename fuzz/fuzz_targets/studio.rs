//! The studio's requests as a page or a script sends them: the JSON of `POST /api/target` and
//! `POST /api/solver` and each line as a WebSocket message, decoded and carried out on a
//! studio of the bundled skeleton (no loop behind it). Whatever arrives, the pose stays finite.
#![no_main]

mod bundled;

use std::sync::Arc;

use libfuzzer_sys::fuzz_target;
use marionette::studio::request::{PageEvent, PageMessage, SolverRequest, TargetRequest, MAX_MESSAGE_BYTES};
use marionette::studio::scene::Scene;
use marionette::studio::{Feed, Studio};

fn finite_pose(studio: &Studio) {
    let scene = studio.scene();
    assert!(
        scene.primary.channels.iter().all(|c| c.is_finite()),
        "a non-finite pose"
    );
}

fuzz_target!(|data: &[u8]| {
    let skeleton = Arc::new(bundled::skeleton().clone());
    let studio = Studio::new(
        Scene::new(skeleton, None),
        Feed::None,
        Vec::new(),
        120.0,
        String::new(),
    );
    if let Ok(r) = TargetRequest::decode(data) {
        assert!(data.len() <= MAX_MESSAGE_BYTES);
        assert!(r.position.is_none_or(|p| p.is_finite()));
        let _ = studio.set_target(&r.effector, r.position, None);
        finite_pose(&studio);
    }
    if let Ok(r) = SolverRequest::decode(data) {
        studio.set_solver(r);
        finite_pose(&studio);
    }
    // Each line a message of one page, in order.
    let mut selected = None;
    for line in String::from_utf8_lossy(data).lines() {
        let Ok(event) = PageEvent::decode(line) else {
            continue;
        };
        assert!(event.event_ms.is_none_or(f64::is_finite));
        match &event.message {
            PageMessage::Drag { position, .. } => assert!(position.is_finite()),
            PageMessage::Swivel { deg } => assert!(deg.is_none_or(f64::is_finite)),
            PageMessage::Timeline { speed, .. } => assert!(speed.is_none_or(|s| (0.0..=4.0).contains(&s))),
            _ => {}
        }
        let _ = studio.apply(event, &mut selected);
        finite_pose(&studio);
    }
    let _ = studio.pose_json();
});

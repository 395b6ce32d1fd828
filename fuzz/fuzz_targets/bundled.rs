//! What several targets share: the bundled skeleton of CMU subject 16.

use std::sync::OnceLock;

use marionette::formats::asf;
use marionette::skeleton::Skeleton;

/// The skeleton of `data/cmu/16.asf`, read once.
pub fn skeleton() -> &'static Skeleton {
    static SKELETON: OnceLock<Skeleton> = OnceLock::new();
    SKELETON.get_or_init(|| {
        asf::parse(include_str!("../../data/cmu/16.asf"))
            .expect("the bundled skeleton loads")
            .skeleton
    })
}

//! Motion clips and their editing (help note §III).
//!
//! A [`Motion`] keeps values as files hold them — rotations in degrees, translations in file
//! units — in f64, so that reading and writing a clip loses nothing; [`Motion::channels_into`]
//! turns a frame into the core's frame vector (radians, f32) without allocating.
//!
//! * [`clip`] — cut, reverse, append, resample, and the transformation of eq. (6)–(10).
//! * [`matching`] — window distance matching, eq. (11), forward and backward.
//! * [`connect`] — connection by interpolation (eq. 12, 14) or blending (eq. 13, 15), loops,
//!   and frame-by-frame blends.
//! * [`seam`] — per-frame rotation and root changes, to judge a transition.
//! * [`plot`] — the picture of a connection.
//! * [`dropouts`] — capture dropouts (a bone's rotation reading exactly zero between far-away
//!   frames): found and filled from their neighbours.
//! * [`calibration`] — a converter's calibration pose (the CMU BVH conversions' T-pose) written
//!   as the first frame.

pub mod calibration;
pub mod clip;
pub mod connect;
pub mod dropouts;
pub mod matching;
pub mod plot;
pub mod seam;

use crate::skeleton::Skeleton;

/// Frames of channel values for one skeleton.
#[derive(Clone, Debug, PartialEq)]
pub struct Motion {
    channels: usize,
    data: Vec<f64>,
    /// The file's number of the first frame (AMC numbers start at 1).
    pub first_frame: i64,
    /// Frames per second (AMC files do not say; CMU captures are 120 Hz).
    pub frame_rate: f64,
}

/// Frame rate of the CMU database, assumed for AMC files.
pub const CMU_FRAME_RATE: f64 = 120.0;

impl Motion {
    /// An empty clip with `channels` values per frame.
    #[must_use]
    pub fn new(channels: usize, frame_rate: f64) -> Motion {
        Motion {
            channels,
            data: Vec::new(),
            first_frame: 1,
            frame_rate,
        }
    }

    /// Values per frame.
    #[must_use]
    pub fn channel_count(&self) -> usize {
        self.channels
    }

    /// Number of frames.
    #[must_use]
    pub fn len(&self) -> usize {
        self.data.len().checked_div(self.channels).unwrap_or(0)
    }

    /// True when there are no frames.
    #[must_use]
    pub fn is_empty(&self) -> bool {
        self.data.is_empty()
    }

    /// Duration in seconds from the first to the last frame.
    #[must_use]
    pub fn duration(&self) -> f64 {
        self.len().saturating_sub(1) as f64 / self.frame_rate
    }

    /// Appends a frame of zeros (the rest pose) and returns it for filling.
    pub fn push_rest_frame(&mut self) -> &mut [f64] {
        let n = self.data.len();
        self.data.resize(n + self.channels, 0.0);
        &mut self.data[n..]
    }

    /// Appends a frame.
    ///
    /// # Panics
    /// When `values.len()` is not [`Motion::channel_count`].
    pub fn push_frame(&mut self, values: &[f64]) {
        assert_eq!(values.len(), self.channels, "frame length");
        self.data.extend_from_slice(values);
    }

    /// Frame `i` (0-based), as the file holds it.
    #[must_use]
    pub fn frame(&self, i: usize) -> &[f64] {
        &self.data[i * self.channels..(i + 1) * self.channels]
    }

    /// Frames `range` as a new clip (frame numbers continue from the first one kept).
    ///
    /// # Panics
    /// When the range is out of bounds.
    #[must_use]
    pub fn slice(&self, range: std::ops::Range<usize>) -> Motion {
        Motion {
            channels: self.channels,
            data: self.data[range.start * self.channels..range.end * self.channels].to_vec(),
            first_frame: self.first_frame + range.start as i64,
            frame_rate: self.frame_rate,
        }
    }

    /// Frame `i`, mutable.
    pub fn frame_mut(&mut self, i: usize) -> &mut [f64] {
        &mut self.data[i * self.channels..(i + 1) * self.channels]
    }

    /// All frames.
    pub fn frames(&self) -> impl ExactSizeIterator<Item = &[f64]> + '_ {
        self.data.chunks_exact(self.channels.max(1))
    }

    /// Writes frame `i` as a core frame vector — rotations in radians — into `out`.
    ///
    /// # Panics
    /// When `out` is shorter than the skeleton's channel count or `i` is out of range.
    pub fn channels_into(&self, skeleton: &Skeleton, i: usize, out: &mut [f32]) {
        frame_to_channels(skeleton, self.frame(i), out);
    }
}

/// Converts file values (degrees) of one frame into a core frame vector (radians, f32).
///
/// # Panics
/// When `values` or `out` is shorter than the skeleton's channel count.
pub fn frame_to_channels(skeleton: &Skeleton, values: &[f64], out: &mut [f32]) {
    for bone in skeleton.bones() {
        for (k, d) in bone.dofs().iter().enumerate() {
            let c = bone.first_channel() + k;
            out[c] = if d.is_rotation() {
                values[c].to_radians() as f32
            } else {
                values[c] as f32
            };
        }
    }
}

/// Converts file values (degrees) of one frame into an f64 channel vector (radians), as the IK
/// solvers and the rig mapping take it.
#[must_use]
pub fn frame_to_radians(skeleton: &Skeleton, values: &[f64]) -> Vec<f64> {
    map_rotations(skeleton, values, f64::to_radians)
}

/// Converts an f64 channel vector (radians) back to file values (degrees).
#[must_use]
pub fn radians_to_frame(skeleton: &Skeleton, channels: &[f64]) -> Vec<f64> {
    map_rotations(skeleton, channels, f64::to_degrees)
}

/// Applies `f` to the rotation channels, copying the others.
fn map_rotations(skeleton: &Skeleton, values: &[f64], f: fn(f64) -> f64) -> Vec<f64> {
    values
        .iter()
        .enumerate()
        .map(|(c, v)| match skeleton.channel_owner(c) {
            Some((_, d)) if d.is_rotation() => f(*v),
            _ => *v,
        })
        .collect()
}

/// Converts a core frame vector back to file values (degrees).
///
/// # Panics
/// When `channels` or `out` is shorter than the skeleton's channel count.
pub fn channels_to_frame(skeleton: &Skeleton, channels: &[f32], out: &mut [f64]) {
    for bone in skeleton.bones() {
        for (k, d) in bone.dofs().iter().enumerate() {
            let c = bone.first_channel() + k;
            out[c] = if d.is_rotation() {
                f64::from(channels[c]).to_degrees()
            } else {
                f64::from(channels[c])
            };
        }
    }
}

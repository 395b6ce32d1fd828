//! What the loop's sources play, outside the tick: the clip player (SLERP resampling to the loop
//! rate, looping, pause/seek/speed), target tracks from CSV or JSON-lines files, and the target
//! line format that live sources (stdin, UDP) read too ([`super::source`] feeds them in).
//!
//! Target lines, in the root's frame (file units), time in seconds:
//!
//! * CSV: `t,effector,x,y,z` or `t,effector,x,y,z,dx,dy,dz` (a header line starting with `t,`
//!   and `#` comments are skipped; rows with the same `t` make one sample);
//! * JSON lines: `{"t":0.5,"targets":[{"effector":"lradius","position":[x,y,z],"direction":[dx,dy,dz]}]}`
//!   (`direction` optional), or one target per line as `{"t":…,"effector":…,"position":…}`.

use std::path::Path;
use std::sync::Arc;

use glam::DVec3;

use super::input::{Target, MAX_EFFECTORS};
use crate::formats::{read_text, FileError, TextError};
use crate::interp::interpolate_frames;
use crate::motion::seam::{beyond_its_steps, quantile};
use crate::motion::Motion;
use crate::skeleton::Skeleton;

/// A clip sampled at the loop's rate: each call gives the frame at the next tick's clip time,
/// SLERP between the two nearest clip frames (eq. 12), rotations in radians.
#[derive(Debug)]
pub struct ClipPlayer {
    skeleton: Arc<Skeleton>,
    motion: Arc<Motion>,
    period_s: f64,
    looping: bool,
    speed: f64,
    paused: bool,
    time: f64,
    started: bool,
    /// Samples of the first frame still to give before the clip starts.
    pre_roll: u64,
    buf: Vec<f64>,
}

/// A command to a running player.
#[derive(Clone, Copy, Debug, PartialEq)]
pub enum PlayerCommand {
    /// Hold the present frame.
    Pause,
    /// Go on.
    Resume,
    /// Pause or resume.
    Toggle,
    /// Jump to a clip time, seconds.
    Seek(f64),
    /// Play at this speed (1 = as captured).
    Speed(f64),
}

impl ClipPlayer {
    /// A player of `motion` at `rate_hz`.
    #[must_use]
    pub fn new(skeleton: Arc<Skeleton>, motion: Arc<Motion>, rate_hz: f64, looping: bool) -> ClipPlayer {
        let n = motion.channel_count();
        ClipPlayer {
            skeleton,
            motion,
            period_s: 1.0 / rate_hz,
            looping,
            speed: 1.0,
            paused: false,
            time: 0.0,
            started: false,
            pre_roll: 0,
            buf: vec![0.0; n],
        }
    }

    /// Channels of a sample (the skeleton's).
    #[must_use]
    pub fn channel_count(&self) -> usize {
        self.skeleton.channel_count()
    }

    /// The clip's length, seconds (time of its last frame).
    #[must_use]
    pub fn duration(&self) -> f64 {
        self.motion.duration()
    }

    /// Samples at the loop rate a whole pass takes: one per tick from clip time 0 to the last
    /// frame.
    #[must_use]
    pub fn samples_per_pass(&self) -> u64 {
        (self.duration() / self.period_s + 1e-9).floor() as u64 + 1
    }

    /// Gives the clip's first frame for `seconds` before the clip starts (the servos move to
    /// it first); those samples carry negative clip times, counting up to 0.
    pub fn set_pre_roll(&mut self, seconds: f64) {
        self.pre_roll = if seconds.is_finite() && seconds > 0.0 {
            (seconds / self.period_s).round() as u64
        } else {
            0
        };
    }

    /// The time between samples (the loop's period), s.
    #[must_use]
    pub fn period_s(&self) -> f64 {
        self.period_s
    }

    /// Samples of the pre-roll still to come.
    #[must_use]
    pub fn pre_roll_samples(&self) -> u64 {
        self.pre_roll
    }

    /// Applies a command.
    pub fn control(&mut self, c: PlayerCommand) {
        match c {
            PlayerCommand::Pause => self.paused = true,
            PlayerCommand::Resume => self.paused = false,
            PlayerCommand::Toggle => self.paused = !self.paused,
            PlayerCommand::Seek(t) if t.is_finite() => {
                self.time = t.clamp(0.0, self.duration());
                self.started = false;
            }
            PlayerCommand::Speed(s) if s.is_finite() && s > 0.0 => self.speed = s,
            PlayerCommand::Seek(_) | PlayerCommand::Speed(_) => {}
        }
    }

    /// The next sample into `out` (radians), returning its clip time; `None` at the end of a
    /// clip played once.
    pub fn next_sample(&mut self, out: &mut [f64]) -> Option<f64> {
        if self.motion.is_empty() {
            return None;
        }
        if self.pre_roll > 0 {
            self.pre_roll -= 1;
            self.sample_at(self.time.clamp(0.0, self.duration()), out);
            return Some(-((self.pre_roll + 1) as f64) * self.period_s);
        }
        if self.started && !self.paused {
            self.time += self.period_s * self.speed;
        }
        self.started = true;
        let d = self.duration();
        if self.time > d + 1e-9 {
            if !self.looping || d <= 0.0 {
                return None;
            }
            self.time = (self.time - d).rem_euclid(d);
        }
        self.sample_at(self.time.min(d), out);
        Some(self.time)
    }

    /// The clip at `time` into `out` (SLERP between the nearest frames, radians).
    fn sample_at(&mut self, time: f64, out: &mut [f64]) {
        let f = (time * self.motion.frame_rate).max(0.0);
        let mut i = f.floor() as usize;
        let mut u = f - i as f64;
        if u > 1.0 - 1e-9 {
            i += 1;
            u = 0.0;
        }
        let last = self.motion.len() - 1;
        let i = i.min(last);
        let j = (i + 1).min(last);
        let s = &self.skeleton;
        interpolate_frames(s, self.motion.frame(i), self.motion.frame(j), u, &mut self.buf);
        let n = s.channel_count().min(out.len());
        for (c, o) in out.iter_mut().enumerate().take(n) {
            let v = self.buf[c];
            *o = match s.channel_owner(c) {
                Some((_, dof)) if dof.is_rotation() => v.to_radians(),
                _ => v,
            };
        }
    }
}

/// What a producer thread did.
#[derive(Clone, Copy, Debug, Default, PartialEq, Eq)]
pub struct ProducerReport {
    /// Messages sent.
    pub sent: u64,
    /// Messages dropped for newer ones (live sources).
    pub dropped: u64,
    /// Lines or datagrams that could not be read as targets.
    pub bad_lines: u64,
    /// Datagrams over [`MAX_DATAGRAM_BYTES`], refused whole.
    pub oversized: u64,
    /// Of those sent, the samples that held a clip's first frame before it started (its
    /// pre-roll).
    pub pre_roll: u64,
}

/// Samples of effector targets over time, read from a file.
#[derive(Clone, Debug, Default, PartialEq)]
pub struct TargetTrack {
    /// (time s, targets) in time order.
    pub samples: Vec<(f64, heapless::Vec<Target, MAX_EFFECTORS>)>,
}

impl TargetTrack {
    /// Reads a CSV or JSON-lines target file; effector names must be in `effectors`.
    ///
    /// # Errors
    /// [`FileError`] with the line and what was expected.
    pub fn load(path: &Path, effectors: &[String]) -> Result<TargetTrack, FileError> {
        let text = read_text(path)?;
        TargetTrack::parse(&text, effectors).map_err(|e| FileError::parse(path, e))
    }

    /// Parses target lines (see the module documentation).
    ///
    /// # Errors
    /// [`TextError`] at the first bad line.
    pub fn parse(text: &str, effectors: &[String]) -> Result<TargetTrack, TextError> {
        let mut track = TargetTrack::default();
        for (n, line) in text.lines().enumerate() {
            let line_no = u32::try_from(n + 1).unwrap_or(u32::MAX);
            let Some((t, targets)) =
                parse_target_line(line, effectors).map_err(|m| TextError::new(line_no, 0, m))?
            else {
                continue;
            };
            if let Some((last_t, _)) = track.samples.last() {
                if t < *last_t {
                    return Err(TextError::new(
                        line_no,
                        0,
                        format!(
                            "time {t} goes back (the previous line has {last_t}); expected times in order"
                        ),
                    ));
                }
            }
            match track.samples.last_mut() {
                Some((last_t, last)) if *last_t == t => {
                    for x in targets {
                        merge_target(last, x);
                    }
                }
                _ => track.samples.push((t, targets)),
            }
        }
        if track.samples.is_empty() {
            return Err(TextError::new(
                crate::formats::last_line(text),
                0,
                "expected `t,effector,x,y,z` lines or JSON lines, found no targets",
            ));
        }
        Ok(track)
    }

    /// What the track played over and over does at each start ([`TrackJump`]): the effector
    /// whose target's move from the last sample back to the first lies furthest
    /// [`beyond_its_steps`]. `None` when no effector appears twice.
    #[must_use]
    pub fn wrap_jump(&self) -> Option<TrackJump> {
        let mut worst: Option<TrackJump> = None;
        for effector in 0..MAX_EFFECTORS {
            let path: Vec<DVec3> = self
                .samples
                .iter()
                .filter_map(|(_, ts)| ts.iter().find(|t| t.effector == effector).map(|t| t.position))
                .collect();
            let (Some(first), Some(last)) = (path.first(), path.last()) else {
                continue;
            };
            let steps: Vec<f64> = path.windows(2).map(|w| (w[1] - w[0]).length()).collect();
            if steps.is_empty() {
                continue;
            }
            let this = TrackJump {
                effector,
                distance: (*first - *last).length(),
                effector_p99: quantile(&steps, 0.99),
            };
            if worst.is_none_or(|w| this.beyond_its_steps() > w.beyond_its_steps()) {
                worst = Some(this);
            }
        }
        worst
    }

    /// Duration from the first to the last sample, seconds.
    #[must_use]
    pub fn duration(&self) -> f64 {
        match (self.samples.first(), self.samples.last()) {
            (Some(a), Some(b)) => b.0 - a.0,
            _ => 0.0,
        }
    }
}

/// What a target track played over and over does at each start: from its last sample back to
/// its first.
#[derive(Clone, Copy, Debug, PartialEq)]
pub struct TrackJump {
    /// The effector (index in the track's list) whose target jumps most beyond its own steps.
    pub effector: usize,
    /// How far its target moves at the wrap, file units.
    pub distance: f64,
    /// Its own move from one sample to the next in the track, 99th percentile, file units.
    pub effector_p99: f64,
}

impl TrackJump {
    /// Whether the track is a cycle: at the wrap no target moves more than three times its own
    /// 99th-percentile step, or 0.002 units if that is more.
    #[must_use]
    pub fn is_seamless(&self) -> bool {
        self.beyond_its_steps() <= 1.0
    }

    fn beyond_its_steps(&self) -> f64 {
        beyond_its_steps(self.distance, self.effector_p99, 0.002)
    }
}

/// Replaces the target of the same effector or appends.
fn merge_target(into: &mut heapless::Vec<Target, MAX_EFFECTORS>, t: Target) {
    if let Some(x) = into.iter_mut().find(|x| x.effector == t.effector) {
        *x = t;
    } else {
        let _ = into.push(t);
    }
}

/// One line of targets: `Ok(None)` for blank, comment and header lines.
///
/// # Errors
/// What is wrong and what was expected.
pub fn parse_target_line(
    line: &str,
    effectors: &[String],
) -> Result<Option<(f64, heapless::Vec<Target, MAX_EFFECTORS>)>, String> {
    let line = line.trim();
    if line.is_empty() || line.starts_with('#') || line.starts_with("t,") {
        return Ok(None);
    }
    let index = |name: &str| {
        effectors.iter().position(|e| e == name).ok_or_else(|| {
            format!(
                "effector '{name}' is not one of the effectors followed ({})",
                effectors.join(", ")
            )
        })
    };
    let mut out = heapless::Vec::new();
    if line.starts_with('{') {
        let v: serde_json::Value =
            serde_json::from_str(line).map_err(|e| format!("expected a JSON object: {e}"))?;
        let t = v
            .get("t")
            .and_then(serde_json::Value::as_f64)
            .ok_or("expected a number field \"t\" (seconds)")?;
        let one = |o: &serde_json::Value| -> Result<Target, String> {
            let name = o
                .get("effector")
                .and_then(serde_json::Value::as_str)
                .ok_or("expected a string field \"effector\"")?;
            let vec3 = |key: &str| -> Result<Option<DVec3>, String> {
                match o.get(key) {
                    None | Some(serde_json::Value::Null) => Ok(None),
                    Some(serde_json::Value::Array(a)) if a.len() == 3 => {
                        let mut x = [0.0; 3];
                        for (k, c) in a.iter().enumerate() {
                            x[k] = c
                                .as_f64()
                                .ok_or_else(|| format!("\"{key}\" must hold three numbers"))?;
                        }
                        Ok(Some(DVec3::from_array(x)))
                    }
                    Some(_) => Err(format!("\"{key}\" must be an array of three numbers")),
                }
            };
            Ok(Target {
                effector: index(name)?,
                position: vec3("position")?.ok_or("expected \"position\": [x, y, z]")?,
                direction: vec3("direction")?,
            })
        };
        if let Some(list) = v.get("targets") {
            let list = list.as_array().ok_or("\"targets\" must be an array")?;
            for o in list {
                merge_target(&mut out, one(o)?);
            }
        } else {
            merge_target(&mut out, one(&v)?);
        }
        return Ok(Some((t, out)));
    }
    let fields: Vec<&str> = line.split(',').map(str::trim).collect();
    if fields.len() != 5 && fields.len() != 8 {
        return Err(format!(
            "expected `t,effector,x,y,z` or `t,effector,x,y,z,dx,dy,dz`, found {} fields",
            fields.len()
        ));
    }
    let num = |k: usize, what: &str| -> Result<f64, String> {
        match fields[k].parse::<f64>() {
            Ok(v) if v.is_finite() => Ok(v),
            _ => Err(format!(
                "field {} ({what}): expected a finite number, found '{}'",
                k + 1,
                fields[k]
            )),
        }
    };
    let t = num(0, "t")?;
    let position = DVec3::new(num(2, "x")?, num(3, "y")?, num(4, "z")?);
    let direction = if fields.len() == 8 {
        Some(DVec3::new(num(5, "dx")?, num(6, "dy")?, num(7, "dz")?))
    } else {
        None
    };
    merge_target(
        &mut out,
        Target {
            effector: index(fields[1])?,
            position,
            direction,
        },
    );
    Ok(Some((t, out)))
}

/// The largest target datagram read, bytes: eight effectors with directions as JSON take
/// under 1 KiB. A longer one is refused whole (counted in [`ProducerReport::oversized`]).
pub const MAX_DATAGRAM_BYTES: usize = 8192;

/// Where a track made from a capture puts its targets.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum TrackFrame {
    /// The tips as captured, in the root's frame (root translation and rotation set to zero):
    /// the paths a tracker on the body would report. A puppet whose spine stays at rest may not
    /// reach all of them.
    Root,
    /// Each tip relative to its limb's parent bone (the clavicle, the hip joint), placed where
    /// that bone is in the rest pose: the limb's own motion, reachable by a rig whose other
    /// joints rest.
    Limb,
}

/// The tips of the `effectors` bones over a clip, one sample per frame — a target track made
/// from a capture.
///
/// # Errors
/// The name of an effector the skeleton does not have.
pub fn clip_track(
    skeleton: &Skeleton,
    motion: &Motion,
    effectors: &[String],
    frame: TrackFrame,
) -> Result<TargetTrack, String> {
    track_of_clip(skeleton, motion, effectors, frame, false)
}

/// [`clip_track`] with each target's pointing direction: the captured direction of the bone the
/// effector's direction target turns ([`super::pointer_bone`]: the hand, the foot), in the
/// same frame as the positions.
///
/// # Errors
/// The name of an effector the skeleton does not have.
pub fn clip_track_pointing(
    skeleton: &Skeleton,
    motion: &Motion,
    effectors: &[String],
    frame: TrackFrame,
) -> Result<TargetTrack, String> {
    track_of_clip(skeleton, motion, effectors, frame, true)
}

fn track_of_clip(
    skeleton: &Skeleton,
    motion: &Motion,
    effectors: &[String],
    frame: TrackFrame,
    pointing: bool,
) -> Result<TargetTrack, String> {
    let bones = effectors
        .iter()
        .map(|n| {
            skeleton.find(n).ok_or_else(|| {
                format!(
                    "no bone named '{n}' in the skeleton; it has: {}",
                    skeleton.bone_names()
                )
            })
        })
        .collect::<Result<Vec<_>, _>>()?;
    if bones.len() > MAX_EFFECTORS {
        return Err(format!("at most {MAX_EFFECTORS} effectors"));
    }
    let mut pose = crate::fk::Pose64::default();
    let mut rest = crate::fk::Pose64::default();
    crate::fk::fk64(skeleton, &vec![0.0; skeleton.channel_count()], &mut rest);
    let limb_parent = |b: usize| {
        let up = skeleton.bones()[b].parent()?;
        skeleton.bones()[up].parent()
    };
    let pointers: Vec<Option<usize>> = bones.iter().map(|&b| super::pointer_bone(skeleton, b)).collect();
    let mut track = TargetTrack::default();
    for f in 0..motion.len() {
        let mut ch = crate::motion::frame_to_radians(skeleton, motion.frame(f));
        if let Some(root) = skeleton.bones().first() {
            for c in root.channels() {
                ch[c] = 0.0;
            }
        }
        crate::fk::fk64(skeleton, &ch, &mut pose);
        let mut targets = heapless::Vec::new();
        for (k, &b) in bones.iter().enumerate() {
            // Limb frame: the limb's motion relative to its parent, put on the rest pose.
            let (position, turn) = match (frame, limb_parent(b)) {
                (TrackFrame::Limb, Some(p)) => {
                    let turn = rest.frame[p] * pose.frame[p].transpose();
                    (rest.tip[p] + turn * (pose.tip[b] - pose.tip[p]), turn)
                }
                _ => (pose.tip[b], glam::DMat3::IDENTITY),
            };
            let direction = pointers[k]
                .filter(|_| pointing)
                .map(|h| turn * (pose.tip[h] - pose.start[h]))
                .filter(|d| d.length() > 1e-9)
                .map(glam::DVec3::normalize);
            let _ = targets.push(Target {
                effector: k,
                position,
                direction,
            });
        }
        track.samples.push((f as f64 / motion.frame_rate, targets));
    }
    Ok(track)
}

/// Writes a track as CSV target lines (see the module documentation).
///
/// # Errors
/// I/O errors.
pub fn write_csv(
    track: &TargetTrack,
    effectors: &[String],
    out: &mut dyn std::io::Write,
) -> std::io::Result<()> {
    writeln!(out, "t,effector,x,y,z")?;
    for (t, targets) in &track.samples {
        for x in targets {
            let p = x.position;
            let name = effectors.get(x.effector).map_or("?", String::as_str);
            match x.direction {
                None => writeln!(out, "{t:.6},{name},{:.6},{:.6},{:.6}", p.x, p.y, p.z)?,
                Some(d) => writeln!(
                    out,
                    "{t:.6},{name},{:.6},{:.6},{:.6},{:.6},{:.6},{:.6}",
                    p.x, p.y, p.z, d.x, d.y, d.z
                )?,
            }
        }
    }
    Ok(())
}

#[cfg(test)]
mod tests {
    use super::*;

    fn names() -> Vec<String> {
        ["lradius", "rtibia"].iter().map(|s| (*s).to_string()).collect()
    }

    #[test]
    fn csv_and_json_lines_read_alike() {
        let csv = "t,effector,x,y,z\n0,lradius,1,2,3\n0,rtibia,4,5,6\n0.5,lradius,1,2,4,0,-1,0\n";
        let json = "{\"t\":0,\"targets\":[{\"effector\":\"lradius\",\"position\":[1,2,3]},{\"effector\":\"rtibia\",\"position\":[4,5,6]}]}\n\
                    {\"t\":0.5,\"effector\":\"lradius\",\"position\":[1,2,4],\"direction\":[0,-1,0]}\n";
        let a = TargetTrack::parse(csv, &names()).unwrap();
        let b = TargetTrack::parse(json, &names()).unwrap();
        assert_eq!(a, b);
        assert_eq!(a.samples.len(), 2);
        assert_eq!(a.samples[0].1.len(), 2);
        assert_eq!(a.samples[1].1[0].direction, Some(DVec3::new(0.0, -1.0, 0.0)));
        assert_eq!(a.duration(), 0.5);
    }

    #[test]
    fn bad_lines_say_where_and_what() {
        for (text, line, says) in [
            ("0,lradius,1,2\n", 1, "fields"),
            ("0,lradius,1,2,3\n0,lhand,1,2,3\n", 2, "not one of"),
            ("0,lradius,1,x,3\n", 1, "field 4 (y)"),
            ("1,lradius,1,2,3\n0,lradius,1,2,3\n", 2, "goes back"),
            ("{\"t\":0,\"effector\":\"lradius\"}\n", 1, "position"),
            (
                "{\"t\":0,\"effector\":\"lradius\",\"position\":[1,2]}\n",
                1,
                "three numbers",
            ),
            ("{t:0}\n", 1, "JSON"),
            ("# nothing\n", 1, "no targets"),
        ] {
            let e = TargetTrack::parse(text, &names()).unwrap_err();
            assert_eq!(e.line, line, "{text:?}: {e:?}");
            assert!(e.message.contains(says), "{text:?}: {}", e.message);
        }
    }
}

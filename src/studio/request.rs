//! What a page or a script asks of the studio, decoded from the bytes it sent: the JSON of
//! `POST /api/target`, `POST /api/solver` and the page's WebSocket messages.
//!
//! Decoding checks everything that needs no scene — the shape, the types, finite numbers, known
//! methods, the timeline's speed range; the scene checks the names. Every refusal is one line.

use glam::DVec3;
use serde_json::Value;

use super::scene::SceneError;
use crate::ik_numeric::IkMethod;

/// The largest request body or WebSocket message the studio reads, bytes. A page's message is
/// under 200 bytes; anything near this is not a page's.
pub const MAX_MESSAGE_BYTES: usize = 64 * 1024;

/// The fastest the timeline plays, times real time.
pub const MAX_SPEED: f64 = 4.0;

/// `POST /api/target`: `{"effector": "lradius", "position": [x, y, z]}` (root frame; `null`
/// releases it).
#[derive(Clone, Debug, PartialEq)]
pub struct TargetRequest {
    /// The effector bone.
    pub effector: String,
    /// Where its tip goes (finite), or `None` to release it.
    pub position: Option<DVec3>,
}

/// `POST /api/solver`: `{"method": "ccd"}`, optionally `"compare": "dls"`.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub struct SolverRequest {
    /// The method that drives the rig.
    pub method: IkMethod,
    /// A second method solved beside it and drawn as a ghost.
    pub compare: Option<IkMethod>,
}

/// One message of the page over its WebSocket.
#[derive(Clone, Debug, PartialEq)]
pub enum PageMessage {
    /// An effector's target moved to a position (root frame, finite).
    Drag {
        /// The effector bone.
        effector: String,
        /// Where its tip goes.
        position: DVec3,
    },
    /// An effector's target let go.
    Release {
        /// The effector bone.
        effector: String,
    },
    /// An effector held where it is while the clip plays.
    Pin {
        /// The effector bone.
        effector: String,
    },
    /// The limb whose swivel circle and limit region are drawn (`None`: none).
    Select {
        /// The effector bone.
        effector: Option<String>,
    },
    /// The methods.
    Solver(SolverRequest),
    /// The swivel angle held fixed (degrees, finite), or searched (`None`).
    Swivel {
        /// Degrees.
        deg: Option<f64>,
    },
    /// The timeline's controls; each one left as it is when absent.
    Timeline {
        /// Play or pause.
        playing: Option<bool>,
        /// Loop at the end.
        looping: Option<bool>,
        /// Times real time, within `0..=`[`MAX_SPEED`].
        speed: Option<f64>,
        /// Seek to this clip time, seconds.
        time: Option<f64>,
    },
    /// Every target released.
    Reset,
}

/// A page's message and the time of the browser event behind it.
#[derive(Clone, Debug, PartialEq)]
pub struct PageEvent {
    /// The message.
    pub message: PageMessage,
    /// The browser's time of the event (ms since the Unix epoch, finite), for the drag latency.
    pub event_ms: Option<f64>,
}

fn object(body: &[u8]) -> Result<Value, String> {
    if body.len() > MAX_MESSAGE_BYTES {
        return Err(format!("over {MAX_MESSAGE_BYTES} bytes"));
    }
    let v: Value = serde_json::from_slice(body).map_err(|e| format!("bad JSON: {e}"))?;
    if !v.is_object() {
        return Err("expected a JSON object".into());
    }
    Ok(v)
}

fn vec3(v: &Value, what: &str) -> Result<DVec3, String> {
    let a = v
        .as_array()
        .filter(|a| a.len() == 3)
        .ok_or_else(|| format!("{what} must be [x, y, z]"))?;
    let mut p = [0.0; 3];
    for (x, v) in p.iter_mut().zip(a) {
        *x = v
            .as_f64()
            .ok_or_else(|| format!("{what} must be three numbers"))?;
    }
    let p = DVec3::from_array(p);
    if !p.is_finite() {
        return Err(format!("{what} must be finite numbers"));
    }
    Ok(p)
}

fn string(v: &Value, key: &str) -> Result<String, String> {
    match v.get(key) {
        Some(Value::String(s)) => Ok(s.clone()),
        Some(_) => Err(format!("`{key}` must be a string")),
        None => Err(format!("missing field `{key}`")),
    }
}

fn method(name: &str) -> Result<IkMethod, String> {
    IkMethod::parse(name).ok_or_else(|| SceneError::UnknownMethod(name.to_string()).to_string())
}

impl TargetRequest {
    /// Decodes a request body.
    ///
    /// # Errors
    /// Why it is refused, in one line.
    pub fn decode(body: &[u8]) -> Result<TargetRequest, String> {
        let v = object(body)?;
        let effector = string(&v, "effector")?;
        let position = match v.get("position") {
            None => return Err("missing field `position`".into()),
            Some(Value::Null) => None,
            Some(p) => Some(vec3(p, "position")?),
        };
        Ok(TargetRequest { effector, position })
    }
}

impl SolverRequest {
    /// Decodes a request body.
    ///
    /// # Errors
    /// Why it is refused, in one line.
    pub fn decode(body: &[u8]) -> Result<SolverRequest, String> {
        let v = object(body)?;
        SolverRequest::from_value(&v, true)
    }

    /// `strict`: a `compare` that is neither a name nor null is refused (the API); the page's
    /// message treats it as none.
    fn from_value(v: &Value, strict: bool) -> Result<SolverRequest, String> {
        let m = method(&string(v, "method")?)?;
        let compare = match v.get("compare") {
            Some(Value::String(c)) => Some(method(c)?),
            None | Some(Value::Null) => None,
            Some(_) if strict => return Err("`compare` must be a method name or null".into()),
            Some(_) => None,
        };
        Ok(SolverRequest { method: m, compare })
    }
}

impl PageEvent {
    /// Decodes a WebSocket text message: `drag`, `release`, `pin`, `pick`/`select`, `solver`,
    /// `swivel`, `timeline`, `reset`.
    ///
    /// # Errors
    /// Why it is refused, in one line.
    pub fn decode(text: &str) -> Result<PageEvent, String> {
        let v = object(text.as_bytes())?;
        let kind = string(&v, "type")?;
        let event_ms = v.get("t").and_then(Value::as_f64).filter(|t| t.is_finite());
        let message = match kind.as_str() {
            "drag" => PageMessage::Drag {
                effector: string(&v, "effector")?,
                position: vec3(v.get("position").unwrap_or(&Value::Null), "position")?,
            },
            "release" => PageMessage::Release {
                effector: string(&v, "effector")?,
            },
            "pin" => PageMessage::Pin {
                effector: string(&v, "effector")?,
            },
            "pick" | "select" => PageMessage::Select {
                effector: match v.get("effector").or_else(|| v.get("bone")) {
                    Some(Value::String(name)) => Some(name.clone()),
                    _ => None,
                },
            },
            "solver" => PageMessage::Solver(SolverRequest::from_value(&v, false)?),
            "swivel" => PageMessage::Swivel {
                deg: match v.get("deg") {
                    Some(Value::Number(n)) => {
                        Some(n.as_f64().filter(|d| d.is_finite()).ok_or("deg must be finite")?)
                    }
                    _ => None,
                },
            },
            "timeline" => {
                let speed = v.get("speed").and_then(Value::as_f64);
                if speed.is_some_and(|s| !(s.is_finite() && (0.0..=MAX_SPEED).contains(&s))) {
                    return Err(format!("speed must be between 0 and {MAX_SPEED}"));
                }
                PageMessage::Timeline {
                    playing: v.get("playing").and_then(Value::as_bool),
                    looping: v.get("looping").and_then(Value::as_bool),
                    speed,
                    time: v.get("time").and_then(Value::as_f64),
                }
            }
            "reset" => PageMessage::Reset,
            other => return Err(format!("unknown message type '{other}'")),
        };
        Ok(PageEvent { message, event_ms })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn targets_and_solvers_decode_and_refuse_in_one_line() {
        let t = TargetRequest::decode(br#"{"effector":"lradius","position":[1,2,3]}"#).unwrap();
        assert_eq!(t.position, Some(DVec3::new(1.0, 2.0, 3.0)));
        let t = TargetRequest::decode(br#"{"effector":"lradius","position":null}"#).unwrap();
        assert_eq!(t.position, None);
        let s = SolverRequest::decode(br#"{"method":"dls","compare":"ccd"}"#).unwrap();
        assert_eq!((s.method, s.compare), (IkMethod::Dls, Some(IkMethod::Ccd)));
        for (body, says) in [
            (
                &br#"{"effector":"lradius","position":[1e999,0,0]}"#[..],
                "bad JSON",
            ),
            (br#"{"effector":"lradius","position":[1,2]}"#, "[x, y, z]"),
            (br#"{"effector":7,"position":[1,2,3]}"#, "must be a string"),
            (b"[1]", "expected a JSON object"),
            (b"\xff", "bad JSON"),
        ] {
            let e = TargetRequest::decode(body).unwrap_err();
            assert!(e.contains(says) && !e.contains('\n'), "{e}");
        }
        assert!(SolverRequest::decode(br#"{"method":"dls","compare":3}"#).is_err());
        let big = format!("{{\"effector\":\"{}\"}}", "x".repeat(MAX_MESSAGE_BYTES));
        assert!(TargetRequest::decode(big.as_bytes())
            .unwrap_err()
            .contains("over"));
    }

    #[test]
    fn page_messages_decode_with_their_checks() {
        let e =
            PageEvent::decode(r#"{"type":"drag","effector":"lradius","position":[1,2,3],"t":5}"#).unwrap();
        assert_eq!(e.event_ms, Some(5.0));
        assert!(matches!(e.message, PageMessage::Drag { .. }));
        let e = PageEvent::decode(r#"{"type":"select","bone":"ltibia"}"#).unwrap();
        assert_eq!(
            e.message,
            PageMessage::Select {
                effector: Some("ltibia".into())
            }
        );
        assert!(PageEvent::decode(r#"{"type":"timeline","speed":9}"#)
            .unwrap_err()
            .contains("between 0 and 4"));
        assert!(PageEvent::decode(r#"{"type":"drag","effector":"lradius"}"#).is_err());
        assert!(PageEvent::decode(r#"{"type":"fly"}"#)
            .unwrap_err()
            .contains("unknown message type"));
        assert_eq!(
            PageEvent::decode(r#"{"type":"solver","method":"cg","compare":1}"#)
                .unwrap()
                .message,
            PageMessage::Solver(SolverRequest {
                method: IkMethod::Cg,
                compare: None
            })
        );
    }
}

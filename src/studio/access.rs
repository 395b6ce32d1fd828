//! Who may talk to the studio: every request is checked before it reaches a handler.
//!
//! The studio moves servos, and a page in the user's browser is an attacker: it can send a
//! "simple" cross-site POST (text/plain, a form) without a preflight, open a WebSocket to any
//! origin, or reach a loopback server under its own name once that name re-resolves to
//! 127.0.0.1 (DNS rebinding). So, in this order:
//!
//! 1. **Host**: only the names this server is reached by — `localhost`, `127.0.0.1`, `[::1]`,
//!    the listening address (on an unspecified address: any IP literal, which no rebinding can
//!    produce, and the machine's host name) — at its port, and the names given with
//!    `--allow-host`. Anything else: 403.
//! 2. **Token**, when there is one (always when the listening address is not loopback): the
//!    `Authorization: Bearer` header, the studio's cookie (HttpOnly, SameSite=Strict), or a
//!    `token` query parameter; the page's URL with `?token=` sets the cookie and redirects to
//!    `/`. Compared in constant time. Missing or wrong: 401.
//! 3. **Origin** on every request that changes state (any method but GET and HEAD) and on the
//!    WebSocket upgrade: the page's own origin (`http://` + the checked Host) or one given with
//!    `--allow-origin`; none at all (curl, scripts) passes. Anything else, `null` included: 403.
//! 4. **Media type** of a POST body: `application/json` only (415), which also makes a
//!    cross-site `fetch` ask a preflight that this server never grants (no CORS headers).
//! 5. **Size**: a declared body over [`MAX_MESSAGE_BYTES`]: 413 before a byte of it is read.
//!
//! Every refusal is one line of text and is counted ([`Refusals`]).

use std::net::{IpAddr, Ipv4Addr, Ipv6Addr};
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::Arc;

use axum::extract::{Request, State};
use axum::http::{header, HeaderMap, HeaderValue, Method, StatusCode};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};
use serde_json::{json, Value};

use super::request::MAX_MESSAGE_BYTES;

/// The environment variable that fixes the token (as `--token` does).
pub const TOKEN_ENV: &str = "MARIONETTE_STUDIO_TOKEN";

/// Bytes of randomness in a generated token (printed as hex: 64 characters).
const TOKEN_BYTES: usize = 32;

/// What the user said about access (the studio's flags).
#[derive(Clone, Debug, Default)]
pub struct AccessOptions {
    /// More host names (or `name:port`) the page may be reached by.
    pub allow_hosts: Vec<String>,
    /// More origins allowed to change state (`scheme://host[:port]`).
    pub allow_origins: Vec<String>,
    /// The token; when `None`, one is generated if the address is not loopback.
    pub token: Option<String>,
}

/// Why a request was refused.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum Refusal {
    /// No Host header, or a name this server is not reached by.
    Host,
    /// The token is missing or wrong.
    Token,
    /// A foreign Origin on a state change or the WebSocket.
    Origin,
    /// A POST body that is not JSON.
    MediaType,
    /// A body or message over the limit.
    TooLarge,
    /// More pages, connections or waiting than the server takes.
    Busy,
}

/// Refusals counted by kind, for `/api/stats` and the summary.
#[derive(Debug, Default)]
pub struct Refusals([AtomicU64; 6]);

impl Refusals {
    /// Counts one.
    pub fn count(&self, r: Refusal) {
        self.0[r as usize].fetch_add(1, Ordering::Relaxed);
    }

    /// The counts by kind.
    #[must_use]
    pub fn json(&self) -> Value {
        let n = |r: Refusal| self.0[r as usize].load(Ordering::Relaxed);
        json!({
            "host": n(Refusal::Host),
            "token": n(Refusal::Token),
            "origin": n(Refusal::Origin),
            "media_type": n(Refusal::MediaType),
            "too_large": n(Refusal::TooLarge),
            "busy": n(Refusal::Busy),
        })
    }

    /// All refusals.
    #[must_use]
    pub fn total(&self) -> u64 {
        self.0.iter().map(|c| c.load(Ordering::Relaxed)).sum()
    }
}

/// A refusal's answer: a status and one line.
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct Refused {
    /// Why.
    pub why: Refusal,
    /// The status.
    pub status: StatusCode,
    /// One line (no newline).
    pub line: String,
}

impl IntoResponse for Refused {
    fn into_response(self) -> Response {
        let mut r = (
            self.status,
            [(header::CONTENT_TYPE, "text/plain; charset=utf-8")],
            self.line + "\n",
        )
            .into_response();
        if self.why == Refusal::Token {
            r.headers_mut().insert(
                header::WWW_AUTHENTICATE,
                HeaderValue::from_static("Bearer realm=\"marionette studio\""),
            );
        }
        r
    }
}

fn refused(why: Refusal, status: StatusCode, line: impl Into<String>) -> Refused {
    Refused {
        why,
        status,
        line: line.into().replace(['\n', '\r'], " "),
    }
}

/// What the checks let through.
#[derive(Clone, Debug, PartialEq, Eq)]
pub enum Admit {
    /// On to the handler.
    Pass,
    /// The page's URL with the right token: set the cookie, go to `/` (the token leaves the
    /// address bar and the history).
    SetCookie,
}

/// The checks of one server.
#[derive(Debug)]
pub struct Access {
    port: u16,
    /// Host names (lower case) with the port they must come with (`None`: this server's).
    hosts: Vec<(String, Option<u16>)>,
    /// Any IP literal is a name of this server (it listens on an unspecified address).
    any_ip: bool,
    origins: Vec<String>,
    token: Option<String>,
    cookie: String,
    loopback: bool,
    /// What was refused.
    pub refused: Refusals,
}

/// `name` and its port from a Host header or an `--allow-host` (lower case; IPv6 bracketed).
fn split_host(host: &str) -> Option<(String, Option<u16>)> {
    let host = host.trim().to_ascii_lowercase();
    if host.is_empty() {
        return None;
    }
    let (name, port) = if host.starts_with('[') {
        let end = host.find(']')?;
        let (name, rest) = host.split_at(end + 1);
        match rest.strip_prefix(':') {
            Some(p) => (name.to_string(), Some(p.parse().ok()?)),
            None if rest.is_empty() => (name.to_string(), None),
            None => return None,
        }
    } else {
        match host.rsplit_once(':') {
            Some((name, p)) => (name.to_string(), Some(p.parse().ok()?)),
            None => (host, None),
        }
    };
    if name.is_empty() || name.contains(['/', '@', ' ', '\\']) {
        return None;
    }
    Some((name, port))
}

fn is_ip_literal(name: &str) -> bool {
    name.parse::<Ipv4Addr>().is_ok()
        || name
            .strip_prefix('[')
            .and_then(|n| n.strip_suffix(']'))
            .is_some_and(|n| n.parse::<Ipv6Addr>().is_ok())
}

/// How an address is written in a URL's host (IPv6 bracketed).
#[must_use]
pub fn url_host(ip: IpAddr) -> String {
    match ip {
        IpAddr::V4(a) => a.to_string(),
        IpAddr::V6(a) => format!("[{a}]"),
    }
}

/// The machine's host name (Linux), for a studio listening on every address.
#[must_use]
pub fn host_name() -> Option<String> {
    let name = std::fs::read_to_string("/proc/sys/kernel/hostname").ok()?;
    let name = name.trim().to_ascii_lowercase();
    (!name.is_empty()).then_some(name)
}

/// `a == b` in time that depends on their lengths only.
#[must_use]
pub fn same_secret(a: &[u8], b: &[u8]) -> bool {
    if a.len() != b.len() {
        return false;
    }
    let diff = a.iter().zip(b).fold(0u8, |acc, (x, y)| acc | (x ^ y));
    std::hint::black_box(diff) == 0
}

/// A new token: 32 bytes from the operating system's generator, as hex.
///
/// # Errors
/// The generator failed.
pub fn new_token() -> std::io::Result<String> {
    let mut bytes = [0u8; TOKEN_BYTES];
    getrandom::fill(&mut bytes).map_err(std::io::Error::other)?;
    Ok(bytes.iter().map(|b| format!("{b:02x}")).collect())
}

fn header_str(headers: &HeaderMap, name: header::HeaderName) -> Option<&str> {
    headers.get(name).and_then(|v| v.to_str().ok())
}

impl Access {
    /// The checks of a server on `ip:port`. A token is generated when the address is not
    /// loopback and none was given.
    ///
    /// # Errors
    /// An `--allow-host` or `--allow-origin` that is not one, an empty token, or no randomness.
    pub fn new(ip: IpAddr, port: u16, options: &AccessOptions) -> Result<Access, String> {
        let mut hosts: Vec<(String, Option<u16>)> = ["localhost", "127.0.0.1", "[::1]"]
            .iter()
            .map(|n| ((*n).to_string(), None))
            .collect();
        let any_ip = ip.is_unspecified();
        if any_ip {
            if let Some(name) = host_name() {
                hosts.push((format!("{name}.local"), None));
                hosts.push((name, None));
            }
        } else {
            hosts.push((url_host(ip), None));
        }
        for h in &options.allow_hosts {
            hosts.push(
                split_host(h).ok_or_else(|| {
                    format!("--allow-host {h}: expected a host name, optionally with :PORT")
                })?,
            );
        }
        let mut origins = Vec::new();
        for o in &options.allow_origins {
            let norm = o.trim().trim_end_matches('/').to_ascii_lowercase();
            let ok = norm.split_once("://").is_some_and(|(scheme, rest)| {
                matches!(scheme, "http" | "https") && split_host(rest).is_some()
            });
            if !ok {
                return Err(format!(
                    "--allow-origin {o}: expected scheme://host[:port], as a browser sends it"
                ));
            }
            origins.push(norm);
        }
        let loopback = ip.is_loopback();
        let token = match &options.token {
            Some(t) if t.trim().is_empty() => {
                return Err(format!("--token (or {TOKEN_ENV}) must not be empty"))
            }
            Some(t) => Some(t.trim().to_string()),
            None if loopback => None,
            None => Some(new_token().map_err(|e| format!("cannot make a token: {e}"))?),
        };
        Ok(Access {
            port,
            hosts,
            any_ip,
            origins,
            token,
            cookie: format!("marionette_studio_{port}"),
            loopback,
            refused: Refusals::default(),
        })
    }

    /// The token requests must carry, if any.
    #[must_use]
    pub fn token(&self) -> Option<&str> {
        self.token.as_deref()
    }

    /// Whether the server listens on loopback only.
    #[must_use]
    pub fn loopback(&self) -> bool {
        self.loopback
    }

    /// The Host header names this server.
    fn host_allowed(&self, host: &str) -> bool {
        let Some((name, port)) = split_host(host) else {
            return false;
        };
        // A Host without a port means port 80.
        let port = port.unwrap_or(80);
        (self.any_ip && is_ip_literal(&name) && port == self.port)
            || self
                .hosts
                .iter()
                .any(|(n, p)| *n == name && p.unwrap_or(self.port) == port)
    }

    fn token_in(&self, headers: &HeaderMap, query: Option<&str>) -> (bool, bool) {
        let Some(token) = &self.token else {
            return (true, false);
        };
        let matches = |t: &str| same_secret(t.trim().as_bytes(), token.as_bytes());
        if let Some(auth) = header_str(headers, header::AUTHORIZATION) {
            if let Some(t) = auth.strip_prefix("Bearer ") {
                return (matches(t), false);
            }
        }
        let from_query = query
            .into_iter()
            .flat_map(|q| q.split('&'))
            .filter_map(|kv| kv.strip_prefix("token="))
            .any(matches);
        if from_query {
            return (true, true);
        }
        let from_cookie = headers
            .get_all(header::COOKIE)
            .iter()
            .filter_map(|v| v.to_str().ok())
            .flat_map(|v| v.split(';'))
            .filter_map(|kv| kv.trim().split_once('='))
            .any(|(k, v)| k == self.cookie && matches(v));
        (from_cookie, false)
    }

    /// The checks, in order, on a request's method, path, query and headers.
    ///
    /// # Errors
    /// The first check that fails.
    pub fn check(
        &self,
        method: &Method,
        path: &str,
        query: Option<&str>,
        headers: &HeaderMap,
    ) -> Result<Admit, Refused> {
        let host = header_str(headers, header::HOST).unwrap_or("");
        if !self.host_allowed(host) {
            return Err(refused(
                Refusal::Host,
                StatusCode::FORBIDDEN,
                format!(
                    "Host '{host}' is not a name of this studio (a page under another name cannot drive the rig; add one with --allow-host)"
                ),
            ));
        }
        let (token_ok, from_query) = self.token_in(headers, query);
        if !token_ok {
            return Err(refused(
                Refusal::Token,
                StatusCode::UNAUTHORIZED,
                "this studio needs its token: open the URL it printed (…/?token=…) or send Authorization: Bearer TOKEN",
            ));
        }
        let upgrade =
            header_str(headers, header::UPGRADE).is_some_and(|u| u.eq_ignore_ascii_case("websocket"));
        let changes_state = !(method == Method::GET || method == Method::HEAD) || upgrade;
        if changes_state {
            if let Some(origin) = header_str(headers, header::ORIGIN).or_else(|| {
                // An Origin that is not text is foreign.
                headers.get(header::ORIGIN).map(|_| "(not text)")
            }) {
                let o = origin.trim().trim_end_matches('/').to_ascii_lowercase();
                let own = format!("http://{}", host.trim().to_ascii_lowercase());
                if o != own && !self.origins.contains(&o) {
                    return Err(refused(
                        Refusal::Origin,
                        StatusCode::FORBIDDEN,
                        format!(
                            "Origin '{origin}' may not drive this studio (only its own page, {own}; add one with --allow-origin)"
                        ),
                    ));
                }
            }
        }
        if method == Method::POST {
            let media = header_str(headers, header::CONTENT_TYPE)
                .map(|c| c.split(';').next().unwrap_or("").trim().to_ascii_lowercase());
            if media.as_deref() != Some("application/json") {
                return Err(refused(
                    Refusal::MediaType,
                    StatusCode::UNSUPPORTED_MEDIA_TYPE,
                    format!(
                        "expected Content-Type: application/json, found {}",
                        media.as_deref().unwrap_or("none")
                    ),
                ));
            }
            let length =
                header_str(headers, header::CONTENT_LENGTH).and_then(|l| l.trim().parse::<u64>().ok());
            if length.is_some_and(|l| l > MAX_MESSAGE_BYTES as u64) {
                return Err(too_large());
            }
        }
        Ok(if from_query && method == Method::GET && path == "/" {
            Admit::SetCookie
        } else {
            Admit::Pass
        })
    }

    /// The cookie that keeps the token for the page.
    fn set_cookie(&self) -> String {
        format!(
            "{}={}; HttpOnly; SameSite=Strict; Path=/",
            self.cookie,
            self.token.as_deref().unwrap_or("")
        )
    }
}

/// 413: a body or message over [`MAX_MESSAGE_BYTES`].
#[must_use]
pub fn too_large() -> Refused {
    refused(
        Refusal::TooLarge,
        StatusCode::PAYLOAD_TOO_LARGE,
        format!("a request body may hold at most {MAX_MESSAGE_BYTES} bytes"),
    )
}

/// 503: the server takes no more of something (pages, waiting).
#[must_use]
pub fn busy(line: impl Into<String>) -> Refused {
    refused(Refusal::Busy, StatusCode::SERVICE_UNAVAILABLE, line)
}

/// Headers on every answer: never framed by another page (clickjacking a drag), never sniffed,
/// never cached, no referrer (a token in the URL stays here).
fn harden(headers: &mut HeaderMap) {
    for (name, value) in [
        (header::X_FRAME_OPTIONS, "DENY"),
        (header::CONTENT_SECURITY_POLICY, "frame-ancestors 'none'"),
        (header::X_CONTENT_TYPE_OPTIONS, "nosniff"),
        (header::REFERRER_POLICY, "no-referrer"),
        (header::CACHE_CONTROL, "no-store"),
    ] {
        headers.insert(name, HeaderValue::from_static(value));
    }
}

/// The middleware: [`Access::check`] before every handler.
pub async fn guard(State(access): State<Arc<Access>>, request: Request, next: Next) -> Response {
    let checked = access.check(
        request.method(),
        request.uri().path(),
        request.uri().query(),
        request.headers(),
    );
    let mut response = match checked {
        Ok(Admit::Pass) => next.run(request).await,
        Ok(Admit::SetCookie) => {
            let mut r = (StatusCode::SEE_OTHER, [(header::LOCATION, "/")]).into_response();
            if let Ok(v) = HeaderValue::from_str(&access.set_cookie()) {
                r.headers_mut().insert(header::SET_COOKIE, v);
            }
            r
        }
        Err(r) => {
            access.refused.count(r.why);
            r.into_response()
        }
    };
    harden(response.headers_mut());
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(list: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in list {
            h.append(*k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    fn loopback() -> Access {
        Access::new(IpAddr::V4(Ipv4Addr::LOCALHOST), 8080, &AccessOptions::default()).unwrap()
    }

    #[test]
    fn hosts_are_the_names_of_this_server_at_its_port() {
        let a = loopback();
        for ok in ["127.0.0.1:8080", "localhost:8080", "LOCALHOST:8080", "[::1]:8080"] {
            assert!(a.host_allowed(ok), "{ok}");
        }
        for bad in [
            "evil.example:8080",
            "127.0.0.1:8081",
            "localhost",
            "",
            "127.0.0.1:x",
            "[::1",
            "10.0.0.1:8080",
            "localhost.evil.example:8080",
        ] {
            assert!(!a.host_allowed(bad), "{bad}");
        }
        let any = Access::new(
            IpAddr::V4(Ipv4Addr::UNSPECIFIED),
            80,
            &AccessOptions {
                allow_hosts: vec!["rig.lan".into(), "proxy:9000".into()],
                ..AccessOptions::default()
            },
        )
        .unwrap();
        for ok in ["10.0.0.1", "10.0.0.1:80", "[fe80::1]", "rig.lan", "proxy:9000"] {
            assert!(any.host_allowed(ok), "{ok}");
        }
        assert!(!any.host_allowed("evil.example"));
        assert!(!any.host_allowed("proxy:80"));
        assert!(any.token().is_some_and(|t| t.len() == 2 * TOKEN_BYTES));
    }

    #[test]
    fn origins_media_types_and_tokens_are_checked() {
        let a = loopback();
        let post =
            |list: &[(&'static str, &str)]| a.check(&Method::POST, "/api/target", None, &headers(list));
        let host = ("host", "127.0.0.1:8080");
        let json = ("content-type", "application/json; charset=utf-8");
        assert_eq!(post(&[host, json]), Ok(Admit::Pass));
        assert_eq!(
            post(&[host, json, ("origin", "http://127.0.0.1:8080")]),
            Ok(Admit::Pass)
        );
        for origin in [
            "http://evil.example",
            "null",
            "http://localhost:8080",
            "https://127.0.0.1:8080",
        ] {
            let e = post(&[host, json, ("origin", origin)]).unwrap_err();
            assert_eq!(
                (e.why, e.status),
                (Refusal::Origin, StatusCode::FORBIDDEN),
                "{origin}"
            );
        }
        let e = post(&[host, ("content-type", "text/plain")]).unwrap_err();
        assert_eq!(e.status, StatusCode::UNSUPPORTED_MEDIA_TYPE);
        let e = post(&[host, json, ("content-length", "10000000")]).unwrap_err();
        assert_eq!(e.status, StatusCode::PAYLOAD_TOO_LARGE);
        // The WebSocket upgrade is a GET, checked like a state change.
        let ws = a.check(
            &Method::GET,
            "/ws",
            None,
            &headers(&[host, ("upgrade", "websocket"), ("origin", "http://evil.example")]),
        );
        assert_eq!(ws.unwrap_err().why, Refusal::Origin);
        // A GET from another page may be sent but never read (no CORS headers).
        assert_eq!(
            a.check(
                &Method::GET,
                "/api/pose",
                None,
                &headers(&[host, ("origin", "http://evil.example")])
            ),
            Ok(Admit::Pass)
        );

        let t = Access::new(
            IpAddr::V4(Ipv4Addr::UNSPECIFIED),
            8080,
            &AccessOptions {
                token: Some("s3cret".into()),
                ..AccessOptions::default()
            },
        )
        .unwrap();
        let get =
            |q: Option<&str>, list: &[(&'static str, &str)]| t.check(&Method::GET, "/", q, &headers(list));
        assert_eq!(get(None, &[host]).unwrap_err().status, StatusCode::UNAUTHORIZED);
        assert_eq!(get(Some("token=nope"), &[host]).unwrap_err().why, Refusal::Token);
        assert_eq!(get(Some("token=s3cret"), &[host]), Ok(Admit::SetCookie));
        assert_eq!(
            get(None, &[host, ("authorization", "Bearer s3cret")]),
            Ok(Admit::Pass)
        );
        assert_eq!(
            get(None, &[host, ("authorization", "Bearer s3cre")])
                .unwrap_err()
                .why,
            Refusal::Token
        );
        assert_eq!(
            get(None, &[host, ("cookie", "a=b; marionette_studio_8080=s3cret")]),
            Ok(Admit::Pass)
        );
        assert_eq!(
            get(None, &[host, ("cookie", "marionette_studio_9999=s3cret")])
                .unwrap_err()
                .why,
            Refusal::Token
        );
        assert!(t.set_cookie().contains("HttpOnly; SameSite=Strict"));
        assert!(Access::new(
            IpAddr::V4(Ipv4Addr::LOCALHOST),
            1,
            &AccessOptions {
                allow_origins: vec!["evil".into()],
                ..AccessOptions::default()
            }
        )
        .is_err());
    }

    #[test]
    fn secrets_compare_by_content() {
        assert!(same_secret(b"abc", b"abc"));
        assert!(!same_secret(b"abc", b"abd"));
        assert!(!same_secret(b"abc", b"abcd"));
        assert_ne!(new_token().unwrap(), new_token().unwrap());
    }
}

//! Which `Host` a request may name, and the headers every page carries.
//!
//! DNS rebinding: a page at `evil.example` whose name the attacker re-points at 127.0.0.1
//! is same-origin with itself, so its `Origin` matches its own `Host` and an origin check
//! alone lets it in. The guard closes that: a request must name this server by an IP
//! address (an IP literal cannot be rebound), by `localhost` or a `*.localhost` name (which
//! resolve to loopback only), or by a name listed in `/server/allowed_hosts`. Everything
//! else gets 403 before any route runs (`/healthz` excepted, so probes may use any name).

use std::net::IpAddr;
use std::sync::Arc;
use std::sync::atomic::Ordering;

use axum::extract::{Request, State};
use axum::http::{HeaderValue, StatusCode, header};
use axum::middleware::Next;
use axum::response::{IntoResponse, Response};

use super::state::AppState;

/// The host of a `Host` header value without its port: `127.0.0.1`, `::1` (from `[::1]`),
/// `lab-pc`. `None` if it is malformed.
fn host_of(value: &str) -> Option<&str> {
    if let Some(rest) = value.strip_prefix('[') {
        let (inside, after) = rest.split_once(']')?;
        return (after.is_empty() || after.strip_prefix(':').is_some_and(is_port))
            .then_some(inside);
    }
    match value.rsplit_once(':') {
        Some((host, port)) if is_port(port) => Some(host),
        Some(_) => None,
        None => Some(value),
    }
}

fn is_port(p: &str) -> bool {
    !p.is_empty() && p.len() <= 5 && p.bytes().all(|b| b.is_ascii_digit())
}

/// Whether `host` (no port) names this server: an IP literal, a loopback name, or one of
/// `allowed` (case-insensitive; a trailing dot is the same name).
pub(crate) fn host_allowed(host: &str, allowed: &[String]) -> bool {
    let name = host.trim_end_matches('.').to_ascii_lowercase();
    if name.is_empty() {
        return false;
    }
    name.parse::<IpAddr>().is_ok()
        || name == "localhost"
        || name.ends_with(".localhost")
        || allowed.iter().any(|a| a.eq_ignore_ascii_case(&name))
}

/// The middleware: 400 without a `Host` (or with two), 403 for a name that is not this
/// server's, otherwise the route.
pub(crate) async fn guard(
    State(state): State<Arc<AppState>>,
    request: Request,
    next: Next,
) -> Response {
    let mut hosts = request.headers().get_all(header::HOST).iter();
    let (Some(value), None) = (hosts.next(), hosts.next()) else {
        state.refused_host.fetch_add(1, Ordering::Relaxed);
        return (
            StatusCode::BAD_REQUEST,
            "a request needs exactly one Host header\n",
        )
            .into_response();
    };
    let value = value.to_str().unwrap_or("");
    let allowed = state.control.settings().server.allowed_hosts.clone();
    if !host_of(value).is_some_and(|h| host_allowed(h, &allowed)) {
        state.refused_host.fetch_add(1, Ordering::Relaxed);
        let shown: String = value.chars().take(80).collect();
        tracing::warn!(host = %shown, "request refused: Host is not a name of this server");
        return (
            StatusCode::FORBIDDEN,
            format!(
                "Host {shown:?} is not a name of this server: use its IP address or localhost, \
                 or add the name to /server/allowed_hosts\n"
            ),
        )
            .into_response();
    }
    next.run(request).await
}

/// The Content-Security-Policy of every page: scripts, styles, images and connections from
/// this server only (inline style attributes are the dashboard's table swatches), and no
/// framing.
const CSP: &str = "default-src 'self'; script-src 'self'; style-src 'self' 'unsafe-inline'; \
                   img-src 'self' data: blob:; connect-src 'self'; frame-ancestors 'none'; \
                   base-uri 'none'; form-action 'none'";

/// Adds `X-Content-Type-Options: nosniff`, `X-Frame-Options: DENY` and the CSP to every
/// response.
pub(crate) async fn security_headers(request: Request, next: Next) -> Response {
    let mut response = next.run(request).await;
    let h = response.headers_mut();
    h.insert(
        header::X_CONTENT_TYPE_OPTIONS,
        HeaderValue::from_static("nosniff"),
    );
    h.insert(header::X_FRAME_OPTIONS, HeaderValue::from_static("DENY"));
    h.insert(
        header::CONTENT_SECURITY_POLICY,
        HeaderValue::from_static(CSP),
    );
    response
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn hosts_that_name_this_server() {
        let allowed = vec!["lab-pc.example.org".to_owned()];
        let ok = |v: &str| host_of(v).is_some_and(|h| host_allowed(h, &allowed));
        for v in [
            "127.0.0.1:8700",
            "127.0.0.1",
            "[::1]:8700",
            "[::1]",
            "192.168.1.20:8700",
            "localhost:8700",
            "LOCALHOST",
            "ftafm.localhost:80",
            "lab-pc.example.org:8700",
            "Lab-PC.Example.Org.",
        ] {
            assert!(ok(v), "{v} refused");
        }
        for v in [
            "evil.example:8700",
            "evil.example",
            "localhost.evil.example",
            "127.0.0.1.nip.io",
            "lab-pc.example.org.evil",
            "",
            "[::1",
            "127.0.0.1:port",
            "example.org:8700:1",
        ] {
            assert!(!ok(v), "{v} allowed");
        }
    }
}

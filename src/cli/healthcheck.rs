//! `facepose healthcheck`: one HTTP/1.1 GET to a running server's readiness route, for the
//! container image's `HEALTHCHECK` (the image has no curl, no shell). Exit 0 on a 2xx answer;
//! otherwise 1 (Docker reserves 2) with a one-line reason on standard error.
//!
//! A plain request over `std::net::TcpStream` with `Connection: close`: no client library, no
//! async runtime, so the check costs a few milliseconds and a few hundred kilobytes of memory
//! every interval.

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream, ToSocketAddrs};
use std::time::{Duration, Instant};

use super::{CliError, Finished};

/// The status a failed check exits with: Docker's "unhealthy" (2 is reserved by Docker).
const UNHEALTHY: u8 = 1;

/// Most bytes of an answer read: the status line, the headers and the start of the body.
const MAX_ANSWER: usize = 16 * 1024;

/// The flags of `facepose healthcheck`.
#[derive(clap::Args)]
pub struct HealthcheckArgs {
    /// The URL to GET (plain http only). Default: http://<FACEPOSE_ADDR>/readyz, with 0.0.0.0
    /// (and [::]) taken as 127.0.0.1 (and [::1]); FACEPOSE_ADDR defaults to 0.0.0.0:8080 as for
    /// `serve`.
    #[arg(long, value_name = "URL")]
    pub url: Option<String>,
    /// The time the whole check may take: connecting, sending, reading the status line.
    #[arg(long, default_value = "2s", value_parser = facepose_service::config::parse_duration)]
    pub timeout: Duration,
}

/// Checks the URL once: `Ok` on a 2xx, else a [`super::Finished`] with status 1 (unhealthy).
pub fn run(a: HealthcheckArgs) -> Result<(), CliError> {
    let url = match a.url {
        Some(u) => u,
        None => default_url(std::env::var("FACEPOSE_ADDR").ok().as_deref())
            .map_err(|m| Finished::new(UNHEALTHY, m))?,
    };
    match check(&url, a.timeout) {
        Ok(status_line) => {
            println!("{url}: {status_line}");
            Ok(())
        }
        Err(reason) => Err(Box::new(Finished::new(
            UNHEALTHY,
            format!("unhealthy: {url}: {reason}"),
        ))),
    }
}

/// `http://<addr>/readyz` for the address `serve` listens on (`FACEPOSE_ADDR`, else its
/// default), with an unspecified host taken as loopback.
fn default_url(addr: Option<&str>) -> Result<String, String> {
    let raw = addr.unwrap_or("0.0.0.0:8080");
    let mut sa: SocketAddr = raw.trim().parse().map_err(|_| {
        format!(
            "FACEPOSE_ADDR {raw:?} is not an IP:port address; give --url http://HOST:PORT/readyz"
        )
    })?;
    if sa.port() == 0 {
        return Err(format!(
            "FACEPOSE_ADDR {raw:?} has port 0 (any free port): give --url http://HOST:PORT/readyz"
        ));
    }
    if sa.ip().is_unspecified() {
        sa.set_ip(match sa {
            SocketAddr::V4(_) => std::net::Ipv4Addr::LOCALHOST.into(),
            SocketAddr::V6(_) => std::net::Ipv6Addr::LOCALHOST.into(),
        });
    }
    Ok(format!("http://{sa}/readyz"))
}

/// A `http://host[:port][/path]` URL taken apart: the `host:port` to connect to and send as
/// `Host`, and the request target.
#[derive(Debug, PartialEq, Eq)]
struct Target {
    authority: String,
    host: String,
    port: u16,
    path: String,
}

fn parse_url(url: &str) -> Result<Target, String> {
    let rest = url
        .strip_prefix("http://")
        .ok_or("not an http:// URL (https is not supported: the check runs next to the server)")?;
    let (authority, path) = match rest.find(['/', '?']) {
        Some(i) if rest[i..].starts_with('/') => (&rest[..i], rest[i..].to_string()),
        Some(i) => (&rest[..i], format!("/{}", &rest[i..])),
        None => (rest, "/".to_string()),
    };
    if authority.is_empty() || authority.contains('@') {
        return Err("the URL has no host (or has user info)".into());
    }
    let (host, port) = match authority.rsplit_once(':') {
        Some((h, p)) if !p.contains(']') => {
            let port = p
                .parse::<u16>()
                .map_err(|_| format!("port {p:?} is not a number from 1 to 65535"))?;
            (h, port)
        }
        _ => (authority, 80),
    };
    if port == 0 {
        return Err("port 0 cannot be connected to".into());
    }
    let host = host.trim_start_matches('[').trim_end_matches(']');
    if host.is_empty() {
        return Err("the URL has no host".into());
    }
    Ok(Target {
        authority: authority.to_string(),
        host: host.to_string(),
        port,
        path,
    })
}

/// Runs the GET; `Ok` holds the status line of a 2xx answer, `Err` the reason of a failure.
fn check(url: &str, timeout: Duration) -> Result<String, String> {
    let deadline = Instant::now()
        .checked_add(timeout)
        .ok_or_else(|| format!("--timeout {timeout:?} is too long"))?;
    let left = || {
        deadline
            .checked_duration_since(Instant::now())
            .filter(|d| !d.is_zero())
            .ok_or_else(|| format!("no answer within {timeout:?} (--timeout)"))
    };
    let t = parse_url(url)?;
    let addrs: Vec<SocketAddr> = (t.host.as_str(), t.port)
        .to_socket_addrs()
        .map_err(|e| format!("cannot resolve {}: {e}", t.host))?
        .collect();
    let mut last = format!("{} resolves to no address", t.host);
    let mut stream = None;
    for addr in addrs {
        match TcpStream::connect_timeout(&addr, left()?) {
            Ok(s) => {
                stream = Some(s);
                break;
            }
            Err(e) => last = format!("cannot connect to {addr}: {e}"),
        }
    }
    let mut stream = stream.ok_or(last)?;
    stream.set_write_timeout(Some(left()?)).map_err(io)?;
    let request = format!(
        "GET {} HTTP/1.1\r\nHost: {}\r\nUser-Agent: facepose-healthcheck\r\nAccept: */*\r\nConnection: close\r\n\r\n",
        t.path, t.authority
    );
    stream
        .write_all(request.as_bytes())
        .map_err(|e| format!("sending the request: {e}"))?;
    let mut answer = Vec::new();
    let mut buf = [0u8; 4096];
    // Read until the connection closes (Connection: close) or enough is here for the reason.
    loop {
        stream.set_read_timeout(Some(left()?)).map_err(io)?;
        match stream.read(&mut buf) {
            Ok(0) => break,
            Ok(n) => {
                answer.extend_from_slice(&buf[..n]);
                if answer.len() >= MAX_ANSWER {
                    break;
                }
            }
            Err(e) if e.kind() == std::io::ErrorKind::Interrupted => {}
            Err(e)
                if matches!(
                    e.kind(),
                    std::io::ErrorKind::WouldBlock | std::io::ErrorKind::TimedOut
                ) =>
            {
                // A complete status line and headers are enough when the body is slow.
                if has_headers(&answer) {
                    break;
                }
                return Err(format!("no answer within {timeout:?} (--timeout)"));
            }
            Err(e) => {
                if has_headers(&answer) {
                    break;
                }
                return Err(format!("reading the answer: {e}"));
            }
        }
    }
    judge(&answer)
}

fn io(e: std::io::Error) -> String {
    e.to_string()
}

fn has_headers(answer: &[u8]) -> bool {
    answer.windows(4).any(|w| w == b"\r\n\r\n")
}

/// The verdict on an HTTP/1.x answer: `Ok(status line)` for 2xx, else the reason, with the
/// start of the body on one line (the server says why it is not ready, e.g. `draining`).
fn judge(answer: &[u8]) -> Result<String, String> {
    if answer.is_empty() {
        return Err("the connection closed without an answer".into());
    }
    let text = String::from_utf8_lossy(answer);
    let status_line = text.lines().next().unwrap_or("").trim();
    // `HTTP/1.x SP DDD [SP reason]` (RFC 9112 §4): three digits, nothing glued to them.
    let code = status_line
        .strip_prefix("HTTP/1.")
        .filter(|r| r.as_bytes().get(1) == Some(&b' '))
        .and_then(|r| {
            r.get(2..5)
                .filter(|_| matches!(r.as_bytes().get(5), None | Some(b' ')))
        })
        .filter(|c| c.bytes().all(|b| b.is_ascii_digit()))
        .and_then(|c| c.parse::<u16>().ok())
        .ok_or_else(|| format!("not an HTTP/1 answer: {:?}", clip(status_line, 80)))?;
    if (200..300).contains(&code) {
        return Ok(status_line.to_string());
    }
    let body = text
        .split_once("\r\n\r\n")
        .map(|(_, b)| b.split_whitespace().collect::<Vec<_>>().join(" "))
        .unwrap_or_default();
    if body.is_empty() {
        Err(status_line.to_string())
    } else {
        Err(format!("{status_line}: {}", clip(&body, 200)))
    }
}

/// `s` cut to at most `n` characters, with an ellipsis when cut.
fn clip(s: &str, n: usize) -> String {
    match s.char_indices().nth(n) {
        Some((i, _)) => format!("{}...", &s[..i]),
        None => s.to_string(),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn default_url_takes_loopback_for_any_address() {
        assert_eq!(default_url(None).unwrap(), "http://127.0.0.1:8080/readyz");
        assert_eq!(
            default_url(Some("0.0.0.0:9000")).unwrap(),
            "http://127.0.0.1:9000/readyz"
        );
        assert_eq!(
            default_url(Some("[::]:9000")).unwrap(),
            "http://[::1]:9000/readyz"
        );
        assert_eq!(
            default_url(Some("10.1.2.3:81")).unwrap(),
            "http://10.1.2.3:81/readyz"
        );
        assert!(
            default_url(Some("127.0.0.1:0"))
                .unwrap_err()
                .contains("--url")
        );
        assert!(
            default_url(Some("localhost"))
                .unwrap_err()
                .contains("--url")
        );
    }

    #[test]
    fn urls_are_taken_apart() {
        let t = parse_url("http://127.0.0.1:8080/readyz").unwrap();
        assert_eq!(
            t,
            Target {
                authority: "127.0.0.1:8080".into(),
                host: "127.0.0.1".into(),
                port: 8080,
                path: "/readyz".into()
            }
        );
        let t = parse_url("http://[::1]:81").unwrap();
        assert_eq!((t.host.as_str(), t.port, t.path.as_str()), ("::1", 81, "/"));
        let t = parse_url("http://example.test?x=1").unwrap();
        assert_eq!((t.port, t.path.as_str()), (80, "/?x=1"));
        assert!(parse_url("https://x/").unwrap_err().contains("https"));
        assert!(parse_url("http://x:0/").is_err());
        assert!(parse_url("http://x:http/").is_err());
        assert!(parse_url("http:///readyz").is_err());
    }

    #[test]
    fn only_2xx_is_healthy() {
        assert_eq!(
            judge(b"HTTP/1.1 200 OK\r\ncontent-length: 2\r\n\r\n{}").unwrap(),
            "HTTP/1.1 200 OK"
        );
        assert!(judge(b"HTTP/1.1 204 No Content\r\n\r\n").is_ok());
        assert_eq!(
            judge(b"HTTP/1.1 503 Service Unavailable\r\n\r\n{\"status\":\n\"draining\"}")
                .unwrap_err(),
            "HTTP/1.1 503 Service Unavailable: {\"status\": \"draining\"}"
        );
        assert_eq!(
            judge(b"HTTP/1.1 301 Moved\r\n\r\n").unwrap_err(),
            "HTTP/1.1 301 Moved"
        );
        assert!(
            judge(b"SSH-2.0-OpenSSH\r\n")
                .unwrap_err()
                .contains("not an HTTP/1")
        );
        assert!(judge(b"").unwrap_err().contains("closed"));
        assert!(
            judge(b"HTTP/1.1 200\r\n\r\n").is_ok(),
            "the reason may be empty"
        );
        for bad in [
            &b"HTTP/1.1 2000 OK\r\n\r\n"[..],
            b"HTTP/1.1X200 OK\r\n\r\n",
            b"HTTP/1.1 +20 OK\r\n\r\n",
            b"HTTP/1.1 20 OK\r\n\r\n",
        ] {
            let e = judge(bad).unwrap_err();
            assert!(e.contains("not an HTTP/1"), "{e}");
        }
    }
}

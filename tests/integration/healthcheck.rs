//! `facepose healthcheck` as the container's HEALTHCHECK runs it: a process against a running
//! server, a closed port, a path that does not answer 2xx and a peer that never answers; its
//! exit status and its one line.

use std::net::TcpListener;
use std::process::{Command, Output};
use std::time::{Duration, Instant};

use facepose_testkit::Endpoint;
use facepose_testkit::process::Process;

const BIN: &str = env!("CARGO_BIN_EXE_facepose");

fn healthcheck(args: &[&str], addr_env: Option<&str>) -> Output {
    let mut cmd = Command::new(BIN);
    cmd.arg("healthcheck").args(args);
    match addr_env {
        Some(a) => cmd.env("FACEPOSE_ADDR", a),
        None => cmd.env_remove("FACEPOSE_ADDR"),
    };
    cmd.output().expect("run facepose healthcheck")
}

fn text(b: &[u8]) -> String {
    String::from_utf8_lossy(b).into_owned()
}

#[test]
fn healthcheck_exit_status() {
    let server = Process::start(BIN, &[]);
    let port = server.addr.port();

    // Ready: 0, from --url and from FACEPOSE_ADDR with the unspecified address.
    let out = healthcheck(&["--url", &server.url("/readyz")], None);
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("200 OK"),
        "{}",
        text(&out.stdout)
    );
    let out = healthcheck(&[], Some(&format!("0.0.0.0:{port}")));
    assert_eq!(out.status.code(), Some(0), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).starts_with(&format!("http://127.0.0.1:{port}/readyz: ")),
        "{}",
        text(&out.stdout)
    );

    // A path that answers 404: 1, with the status and the server's reason on one line.
    let out = healthcheck(&["--url", &server.url("/no-such-route")], None);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(
        err.contains("404 Not Found") && err.contains("not_found"),
        "{err}"
    );
    assert_eq!(err.trim_end().lines().count(), 1, "{err}");
    drop(server);

    // A closed port (bound, then released): 1, naming the connection's error.
    let closed = {
        let l = TcpListener::bind("127.0.0.1:0").unwrap();
        l.local_addr().unwrap()
    };
    let out = healthcheck(&["--url", &format!("http://{closed}/readyz")], None);
    assert_eq!(out.status.code(), Some(1));
    let err = text(&out.stderr);
    assert!(err.contains("cannot connect"), "{err}");
    // The server's port once it has exited, through FACEPOSE_ADDR.
    let out = healthcheck(&[], Some(&format!("127.0.0.1:{port}")));
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));

    // A peer that accepts the connection (the kernel's backlog) and never answers: 1 once
    // --timeout has passed.
    let silent = TcpListener::bind("127.0.0.1:0").unwrap();
    let t = Instant::now();
    let out = healthcheck(
        &[
            "--url",
            &format!("http://{}/readyz", silent.local_addr().unwrap()),
            "--timeout",
            "300ms",
        ],
        None,
    );
    assert_eq!(out.status.code(), Some(1));
    assert!(
        text(&out.stderr).contains("no answer within"),
        "{}",
        text(&out.stderr)
    );
    assert!(t.elapsed() < Duration::from_secs(3), "{:?}", t.elapsed());

    // A bad FACEPOSE_ADDR is unhealthy too (Docker reserves 2), and says what to do.
    let out = healthcheck(&[], Some("localhost"));
    assert_eq!(out.status.code(), Some(1));
    assert!(text(&out.stderr).contains("--url"), "{}", text(&out.stderr));
}

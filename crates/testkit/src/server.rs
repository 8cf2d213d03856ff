//! `facepose_service::serve` in the test process: the flags of `facepose serve` parsed as the
//! binary parses them, a loopback listener on a free port, and a runtime of its own on a thread
//! of its own, so that a test that blocks (a raw socket read, a sleep) never stalls its server.
//! Stopping it is the drain SIGTERM starts; what [`serve`](facepose_service::serve) returned is
//! the exit.

use std::net::SocketAddr;
use std::path::PathBuf;
use std::sync::atomic::{AtomicU64, Ordering};
use std::time::{Duration, Instant};

use clap::Parser;
use facepose_service::{ServeArgs, ServeError};

use crate::Endpoint;
use crate::logs;
use crate::raw::raw_get;

#[derive(Parser)]
struct Flags {
    #[command(flatten)]
    serve: ServeArgs,
}

/// A server in the test process; stopped (and waited for) when dropped.
pub struct Server {
    /// The address it listens on.
    pub addr: SocketAddr,
    /// `http://addr`.
    pub base: String,
    /// Its replica name: its log lines are filed under it.
    pub replica: String,
    shutdown: Option<tokio::sync::oneshot::Sender<()>>,
    exit: std::sync::mpsc::Receiver<Result<(), ServeError>>,
    exited: Option<Result<(), String>>,
    thread: Option<std::thread::JoinHandle<()>>,
    token_file: Option<PathBuf>,
    started: Instant,
}

impl Endpoint for Server {
    fn base(&self) -> &str {
        &self.base
    }

    fn addr(&self) -> SocketAddr {
        self.addr
    }
}

fn unique(tag: &str) -> String {
    static N: AtomicU64 = AtomicU64::new(0);
    format!(
        "{tag}-{}-{}",
        std::process::id(),
        N.fetch_add(1, Ordering::Relaxed)
    )
}

impl Server {
    /// Serves with the flags `args` of `facepose serve` (`--addr` is a free loopback port;
    /// `--drain-timeout` 2s unless given; `--replica` a name of its own unless given) and waits
    /// for `/readyz`.
    pub fn start(args: &[&str]) -> Server {
        Self::start_inner(args, None)
    }

    /// [`Server::start`] with `token` as the admin token (given the way an operator gives it
    /// in a file, `--admin-token-file`).
    pub fn start_admin(args: &[&str], token: &str) -> Server {
        Self::start_inner(args, Some(token))
    }

    fn start_inner(args: &[&str], token: Option<&str>) -> Server {
        logs::install();
        let started = Instant::now();
        let mut argv: Vec<String> = vec![
            "facepose-serve".into(),
            "--addr".into(),
            "127.0.0.1:0".into(),
        ];
        if !args.contains(&"--drain-timeout") {
            argv.extend(["--drain-timeout".into(), "2s".into()]);
        }
        let replica = match args.iter().position(|a| *a == "--replica") {
            Some(i) => args[i + 1].to_string(),
            None => {
                let r = unique("test");
                argv.extend(["--replica".into(), r.clone()]);
                r
            }
        };
        let token_file = token.map(|t| {
            let f = std::env::temp_dir().join(format!("facepose-{}.token", unique("admin")));
            std::fs::write(&f, format!("{t}\n")).expect("the token file");
            argv.extend(["--admin-token-file".into(), f.display().to_string()]);
            f
        });
        argv.extend(args.iter().map(|a| a.to_string()));
        let level = match args.iter().position(|a| *a == "--log") {
            Some(i) if args[i + 1].starts_with("debug") => tracing::Level::DEBUG,
            Some(i) if args[i + 1].starts_with("trace") => tracing::Level::TRACE,
            _ => tracing::Level::INFO,
        };
        logs::watch(&replica, level);
        let flags = Flags::try_parse_from(&argv).unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        let cfg = flags
            .serve
            .validate()
            .unwrap_or_else(|e| panic!("{argv:?}: {e}"));
        let workers = cfg.workers.min(2);
        let (addr_tx, addr_rx) = std::sync::mpsc::channel();
        let (exit_tx, exit) = std::sync::mpsc::channel();
        let (shutdown, stop) = tokio::sync::oneshot::channel::<()>();
        let thread = std::thread::Builder::new()
            .name(format!("server {replica}"))
            .spawn(move || {
                let runtime = tokio::runtime::Builder::new_multi_thread()
                    .worker_threads(workers)
                    .max_blocking_threads(workers + 4)
                    .enable_all()
                    .build()
                    .expect("a runtime");
                let result = runtime.block_on(async move {
                    let listener = tokio::net::TcpListener::bind(cfg.addr).await?;
                    let _ = addr_tx.send(listener.local_addr()?);
                    facepose_service::serve(cfg, listener, async {
                        let _ = stop.await;
                    })
                    .await
                });
                runtime.shutdown_timeout(Duration::from_millis(100));
                let _ = exit_tx.send(result);
            })
            .expect("the server's thread");
        let addr = match addr_rx.recv_timeout(Duration::from_secs(30)) {
            Ok(a) => a,
            Err(_) => panic!(
                "the server did not bind: {:?}; logs:\n{}",
                exit.try_recv(),
                logs::of(&replica)
            ),
        };
        let server = Server {
            addr,
            base: format!("http://{addr}"),
            replica,
            shutdown: Some(shutdown),
            exit,
            exited: None,
            thread: Some(thread),
            token_file,
            started,
        };
        server.wait_ready(Duration::from_secs(30));
        server
    }

    /// Polls `/readyz` until it answers 200; the time since the start.
    pub fn wait_ready(&self, limit: Duration) -> Duration {
        let t = Instant::now();
        while t.elapsed() < limit {
            if raw_get(self.addr, "/readyz").is_some_and(|(s, _)| s == 200) {
                return self.started.elapsed();
            }
            if let Ok(r) = self.exit.try_recv() {
                panic!("the server stopped: {r:?}; logs:\n{}", self.logs());
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        panic!("not ready after {limit:?}; logs:\n{}", self.logs());
    }

    /// Its log lines so far.
    pub fn logs(&self) -> String {
        logs::of(&self.replica)
    }

    /// Starts the drain, as SIGTERM does.
    pub fn terminate(&mut self) {
        if let Some(s) = self.shutdown.take() {
            let _ = s.send(());
        }
    }

    /// Waits at most `limit` for `serve` to return; what it returned (its error as text).
    ///
    /// Async, so that the test's own clients keep running meanwhile: a drain closes a
    /// connection only once its client has answered the server's GOAWAY and PING.
    pub async fn wait_exit(&mut self, limit: Duration) -> Option<Result<(), String>> {
        let t = Instant::now();
        while self.exited.is_none() && t.elapsed() < limit {
            if let Ok(r) = self.exit.try_recv() {
                self.exited = Some(r.map_err(|e| e.to_string()));
                break;
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        self.exited.clone()
    }
}

impl Drop for Server {
    fn drop(&mut self) {
        self.terminate();
        if let Some(t) = self.thread.take() {
            let _ = t.join();
        }
        if let Some(f) = &self.token_file {
            let _ = std::fs::remove_file(f);
        }
    }
}

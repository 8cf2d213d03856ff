//! The real `facepose serve` binary as a child process (the test names the binary: Cargo
//! gives its path to the tests of the package that builds it), for what only a process
//! shows: signals, exit statuses, kill -9, start-up errors as an operator sees them.

use std::io::{BufRead, BufReader};
use std::net::SocketAddr;
use std::process::{Child, Command, ExitStatus, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::Endpoint;
use crate::raw::raw_get;

/// A running `facepose serve`; killed when dropped.
pub struct Process {
    child: Child,
    /// The address it listens on.
    pub addr: SocketAddr,
    /// `http://addr`.
    pub base: String,
    logs: Arc<Mutex<String>>,
    started: Instant,
}

impl Process {
    /// Starts `facepose serve --addr 127.0.0.1:0 <args>` and waits for `/readyz`.
    pub fn start(bin: &str, args: &[&str]) -> Process {
        Self::start_in(bin, args, None)
    }

    /// As [`Server::start`], in a working directory.
    pub fn start_in(bin: &str, args: &[&str], dir: Option<&std::path::Path>) -> Process {
        Self::start_with(bin, args, dir, &[])
    }

    /// As [`Server::start_in`], with environment variables.
    pub fn start_with(
        bin: &str,
        args: &[&str],
        dir: Option<&std::path::Path>,
        envs: &[(&str, &str)],
    ) -> Process {
        let started = Instant::now();
        let mut cmd = Command::new(bin);
        cmd.args(["serve", "--addr", "127.0.0.1:0"]);
        if !args.contains(&"--log") {
            cmd.args(["--log", "info"]);
        }
        cmd.args(args)
            .env_remove("FACEPOSE_ADDR")
            .env_remove("FACEPOSE_LOG_FORMAT")
            .env_remove("FACEPOSE_ADMIN_TOKEN")
            .env_remove("FACEPOSE_ADMIN_TOKEN_FILE")
            .envs(envs.iter().copied())
            .stdin(Stdio::null())
            .stdout(Stdio::null())
            .stderr(Stdio::piped());
        if let Some(d) = dir {
            cmd.current_dir(d);
        }
        let mut child = cmd.spawn().expect("spawn facepose serve");
        let stderr = child.stderr.take().unwrap();
        let logs = Arc::new(Mutex::new(String::new()));
        let (tx, rx) = std::sync::mpsc::channel();
        let sink = logs.clone();
        std::thread::spawn(move || {
            for line in BufReader::new(stderr).lines() {
                let Ok(line) = line else { break };
                if let Some(a) = line.split("addr=").nth(1) {
                    let a = a.split_whitespace().next().unwrap_or("").to_string();
                    let _ = tx.send(a);
                }
                let mut l = sink.lock().unwrap();
                l.push_str(&line);
                l.push('\n');
            }
        });
        let addr: SocketAddr = match rx.recv_timeout(Duration::from_secs(30)) {
            Ok(a) => a.parse().expect("bound address"),
            Err(_) => {
                let _ = child.kill();
                panic!(
                    "the server did not log its address; logs:\n{}",
                    logs.lock().unwrap()
                );
            }
        };
        let server = Process {
            child,
            addr,
            base: format!("http://{addr}"),
            logs,
            started,
        };
        server.wait_ready(Duration::from_secs(30));
        server
    }

    /// Polls `/readyz` until it answers 200.
    pub fn wait_ready(&self, limit: Duration) -> Duration {
        let t = Instant::now();
        while t.elapsed() < limit {
            if raw_get(self.addr, "/readyz").is_some_and(|(s, _)| s == 200) {
                return self.started.elapsed();
            }
            std::thread::sleep(Duration::from_millis(5));
        }
        panic!("not ready after {limit:?}; logs:\n{}", self.logs());
    }

    /// Its stderr (the logs) so far.
    pub fn logs(&self) -> String {
        self.logs.lock().unwrap().clone()
    }

    /// Its process id.
    pub fn pid(&self) -> u32 {
        self.child.id()
    }

    /// Kills the process with SIGKILL and waits for it.
    pub fn kill9(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }

    /// Sends SIGTERM.
    pub fn terminate(&self) {
        let ok = Command::new("kill")
            .args(["-TERM", &self.pid().to_string()])
            .status()
            .expect("kill")
            .success();
        assert!(ok, "kill -TERM failed");
    }

    /// Waits for the process to exit, at most `limit`.
    ///
    /// Async, so that the test's own clients keep running meanwhile: a drain closes a
    /// connection only once its client has answered the server's GOAWAY and PING, which a
    /// client whose runtime is blocked in a sleep never does (the drain then waits for its cap).
    pub async fn wait_exit(&mut self, limit: Duration) -> Option<ExitStatus> {
        let t = Instant::now();
        while t.elapsed() < limit {
            if let Ok(Some(s)) = self.child.try_wait() {
                return Some(s);
            }
            tokio::time::sleep(Duration::from_millis(10)).await;
        }
        None
    }
}

impl Drop for Process {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

impl Endpoint for Process {
    fn base(&self) -> &str {
        &self.base
    }

    fn addr(&self) -> SocketAddr {
        self.addr
    }
}

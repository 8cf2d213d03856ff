//! The log lines of servers running in the test process, kept apart: every event a server
//! logs is under its `server{replica=...}` span (`facepose_service::serve`), and this layer
//! files each event under the replica of its outermost `server` span, at the level the test
//! asked of that server. Set `FACEPOSE_TEST_LOG=1` to also see them on stderr.

use std::collections::HashMap;
use std::fmt::Write;
use std::sync::{Mutex, OnceLock};

use tracing::field::{Field, Visit};
use tracing::span::{Attributes, Id};
use tracing::{Event, Level, Subscriber};
use tracing_subscriber::layer::{Context, SubscriberExt};
use tracing_subscriber::registry::LookupSpan;
use tracing_subscriber::{Layer, Registry};

struct Book {
    /// Per replica: the most verbose level kept, and the lines.
    servers: HashMap<String, (Level, String)>,
}

fn book() -> &'static Mutex<Book> {
    static BOOK: OnceLock<Mutex<Book>> = OnceLock::new();
    BOOK.get_or_init(|| {
        Mutex::new(Book {
            servers: HashMap::new(),
        })
    })
}

fn lock() -> std::sync::MutexGuard<'static, Book> {
    book().lock().unwrap_or_else(|e| e.into_inner())
}

/// Installs the capturing subscriber (once per test process).
pub fn install() {
    static ONCE: OnceLock<()> = OnceLock::new();
    ONCE.get_or_init(|| {
        let _ = tracing::subscriber::set_global_default(Registry::default().with(Capture));
    });
}

/// Starts keeping the lines of `replica` at `level` and more severe.
pub fn watch(replica: &str, level: Level) {
    lock()
        .servers
        .insert(replica.to_string(), (level, String::new()));
}

/// The lines `replica` logged so far.
pub fn of(replica: &str) -> String {
    lock()
        .servers
        .get(replica)
        .map(|(_, l)| l.clone())
        .unwrap_or_default()
}

/// A span's `replica` field.
struct Replica(String);

struct Capture;

#[derive(Default)]
struct Line(String);

impl Visit for Line {
    fn record_str(&mut self, field: &Field, value: &str) {
        if field.name() == "message" {
            let _ = write!(self.0, " {value}");
        } else {
            let _ = write!(self.0, " {}={value}", field.name());
        }
    }

    fn record_debug(&mut self, field: &Field, value: &dyn std::fmt::Debug) {
        if field.name() == "message" {
            let _ = write!(self.0, " {value:?}");
        } else {
            let _ = write!(self.0, " {}={value:?}", field.name());
        }
    }
}

impl<S: Subscriber + for<'a> LookupSpan<'a>> Layer<S> for Capture {
    fn on_new_span(&self, attrs: &Attributes<'_>, id: &Id, ctx: Context<'_, S>) {
        if attrs.metadata().name() != "server" {
            return;
        }
        let mut fields = Line::default();
        attrs.record(&mut fields);
        let replica = fields
            .0
            .split_whitespace()
            .find_map(|kv| kv.strip_prefix("replica="))
            .unwrap_or("")
            .to_string();
        if let Some(span) = ctx.span(id) {
            span.extensions_mut().insert(Replica(replica));
        }
    }

    fn on_event(&self, event: &Event<'_>, ctx: Context<'_, S>) {
        let Some(scope) = ctx.event_scope(event) else {
            return;
        };
        let Some(replica) = scope
            .from_root()
            .find_map(|s| s.extensions().get::<Replica>().map(|r| r.0.clone()))
        else {
            return;
        };
        let level = *event.metadata().level();
        let mut line = Line(format!("{level} {}:", event.metadata().target()));
        event.record(&mut line);
        if std::env::var_os("FACEPOSE_TEST_LOG").is_some() {
            eprintln!("[{replica}] {}", line.0);
        }
        let mut book = lock();
        if let Some((max, lines)) = book.servers.get_mut(&replica)
            && level <= *max
        {
            lines.push_str(&line.0);
            lines.push('\n');
        }
    }
}

//! [`Loopback`]: a database served on 127.0.0.1, on a port the system picks, with the
//! default settings, for a walk or a tool in the same process (`railview walk DIR`, the
//! sweep's standard walk).

use std::sync::Arc;

use tokio::sync::oneshot;
use tokio::task::JoinHandle;

use super::{run, ServedDb, ServerConfig, ServerError, ServerStats};
use crate::client::ServerUrl;

/// A running loopback server; [`Loopback::stop`] ends it (dropping it stops it too).
pub struct Loopback {
    /// Where it answers: `http://127.0.0.1:PORT`.
    pub url: ServerUrl,
    stop: oneshot::Sender<()>,
    task: JoinHandle<Result<(), ServerError>>,
}

impl Loopback {
    /// Serves `db` on a new tokio task of the current runtime.
    pub async fn start(db: ServedDb) -> Result<Loopback, ServerError> {
        let listener = tokio::net::TcpListener::bind("127.0.0.1:0")
            .await
            .map_err(ServerError::Bind)?;
        let addr = listener.local_addr().map_err(ServerError::Bind)?;
        let url = ServerUrl::parse(&format!("http://{addr}"))
            .map_err(|e| ServerError::Task(e.to_string()))?;
        let (stop, stopped) = oneshot::channel::<()>();
        let shutdown = async {
            // A dropped sender also stops the server.
            let _ = stopped.await;
        };
        let stats = Arc::new(ServerStats::default());
        let task = tokio::spawn(run(listener, db, ServerConfig::default(), stats, shutdown));
        Ok(Loopback { url, stop, task })
    }

    /// Stops the server and waits for it: the error that stopped it early, if any.
    pub async fn stop(self) -> Result<(), ServerError> {
        // The server may have stopped already; its own error is the one to report.
        let _ = self.stop.send(());
        self.task
            .await
            .map_err(|e| ServerError::Task(e.to_string()))?
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_loopback_server_answers_on_127_0_0_1_and_stops() {
        let dir = tempfile::tempdir().unwrap();
        crate::walk::synth::write_synthetic(dir.path(), &Default::default()).unwrap();
        let rt = tokio::runtime::Runtime::new().unwrap();
        rt.block_on(async {
            let server = Loopback::start(ServedDb::open(dir.path()).unwrap())
                .await
                .unwrap();
            assert!(
                server.url.authority.starts_with("127.0.0.1:"),
                "{:?}",
                server.url
            );
            server.stop().await.unwrap();
        });
    }
}

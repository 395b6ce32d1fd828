//! Floods a running studio with WebSockets: `ROUNDS` times, `N` upgrade requests at once (with
//! the studio's own Origin), held `HOLD` seconds without reading, then closed. Prints what each
//! round got: upgrades, 503s (the page limit), connections closed unanswered.
//!
//! `cargo run --release --example studio_flood -- 127.0.0.1:18490 200 1.5 9`

use std::net::TcpStream;
use std::time::Duration;

use tungstenite::client::IntoClientRequest;

fn main() {
    let args: Vec<String> = std::env::args().skip(1).collect();
    let [addr, n, hold, rounds] = &args[..] else {
        eprintln!("usage: studio_flood HOST:PORT N HOLD_SECONDS ROUNDS");
        std::process::exit(2);
    };
    let n: usize = n.parse().expect("N");
    let hold = Duration::from_secs_f64(hold.parse().expect("HOLD_SECONDS"));
    let rounds: usize = rounds.parse().expect("ROUNDS");
    let origin = format!("http://{addr}");
    for round in 1..=rounds {
        let results: Vec<Result<tungstenite::WebSocket<TcpStream>, u16>> = std::thread::scope(|scope| {
            let handles: Vec<_> = (0..n)
                .map(|_| {
                    scope.spawn(|| {
                        let mut req = format!("ws://{addr}/ws").into_client_request().unwrap();
                        req.headers_mut().insert("Origin", origin.parse().unwrap());
                        let stream = TcpStream::connect(addr).map_err(|_| 0u16)?;
                        match tungstenite::client(req, stream) {
                            Ok((ws, _)) => Ok(ws),
                            Err(tungstenite::HandshakeError::Failure(tungstenite::Error::Http(r))) => {
                                Err(r.status().as_u16())
                            }
                            Err(_) => Err(0),
                        }
                    })
                })
                .collect();
            handles.into_iter().map(|h| h.join().unwrap()).collect()
        });
        let count = |f: &dyn Fn(&Result<_, u16>) -> bool| results.iter().filter(|r| f(r)).count();
        println!(
            "round {round}: {} upgraded, {} answered 503, {} closed unanswered",
            count(&|r| r.is_ok()),
            count(&|r| r.as_ref().err() == Some(&503)),
            count(&|r| r.as_ref().err() == Some(&0)),
        );
        std::thread::sleep(hold);
    }
}

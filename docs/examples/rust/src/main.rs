//! A MORPH application in Rust (deploy/missions/morph.yaml, as run by `zab sim` or `zab demo`).
//!
//! It puts a target reference on the lsv's input key `target_reference` (tcp/127.0.0.1:7503)
//! and prints what the gcv's bridge publishes after the acoustic hop, `lsv/target_reference`
//! (tcp/127.0.0.1:7502). Payloads are msgpack maps whose shape is the key's payload schema
//! (`zab schema --payloads deploy/missions/morph.yaml`).
//!
//!     cargo run -- tcp/127.0.0.1:7503 tcp/127.0.0.1:7502

use serde::{Deserialize, Serialize};
use zenoh::bytes::Encoding;

#[derive(Debug, Serialize, Deserialize)]
struct Vector {
    x: f64, // heading, rad, 0..6.2831 in 8 bits
    y: f64, // pitch, rad, ±0.052 in 6 bits
}

#[derive(Debug, Serialize, Deserialize)]
struct TargetReference {
    vector: Vector,
}

fn client(endpoint: &str) -> zenoh::Result<zenoh::Config> {
    let mut config = zenoh::Config::default();
    config.insert_json5("mode", r#""client""#)?;
    config.insert_json5("connect/endpoints", &format!(r#"["{endpoint}"]"#))?;
    config.insert_json5("scouting/multicast/enabled", "false")?;
    Ok(config)
}

#[tokio::main]
async fn main() -> zenoh::Result<()> {
    let mut args = std::env::args().skip(1);
    let lsv = args.next().unwrap_or_else(|| "tcp/127.0.0.1:7503".into());
    let gcv = args.next().unwrap_or_else(|| "tcp/127.0.0.1:7502".into());

    let at_gcv = zenoh::open(client(&gcv)?).await?;
    let subscriber = at_gcv.declare_subscriber("lsv/target_reference").await?;

    let at_lsv = zenoh::open(client(&lsv)?).await?;
    let value = TargetReference { vector: Vector { x: 3.0, y: 0.02 } };
    // to_vec_named: a map with field names, as the bridge expects (not a positional array)
    let payload = rmp_serde::to_vec_named(&value)?;
    at_lsv
        .put("target_reference", payload)
        .encoding(Encoding::from("application/msgpack"))
        .await?;
    println!("put {value:?} at lsv; waiting for it at gcv (next lsv TDMA slot)...");

    while let Ok(sample) = subscriber.recv_async().await {
        let bytes = sample.payload().to_bytes();
        let received: TargetReference = rmp_serde::from_slice(&bytes)?;
        println!("{} ({}): {received:?}", sample.key_expr(), sample.encoding());
        break;
    }
    at_lsv.close().await?;
    at_gcv.close().await?;
    Ok(())
}

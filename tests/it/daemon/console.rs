//! The console in a real browser: headless chromium (through chromedriver) against the gateway
//! over the simulated seed plant and a real mosquitto. What the page shows is compared with
//! what the broker carries; what it sends is checked byte for byte in the simulators'
//! journals. Screenshots of every page are written to `$RTU2MQTT_SCREENSHOTS` when set (the
//! ones in docs/console/ come from here), else to a temporary directory.

use crate::support;

use std::path::PathBuf;
use std::time::{Duration, Instant, SystemTime, UNIX_EPOCH};

use rtu2mqtt_modbus::timing::{CharFormat, LineTiming, Parity};
use rtu2mqtt_sim::{self as sim, SeedPlant};
use support::browser::Locator;
use support::hex::{self, writes};
use support::{free_port, Browser, Mosquitto, PlantBench, PlantConfig};
use tokio::io::{AsyncReadExt, AsyncWriteExt};

const TOKEN: &str = "console-test-token-0123456789";
const DUST: u8 = 1;
/// The label a profile may carry, shown by the page as text, never run.
const HOSTILE_LABEL: &str = "<script>document.title='pwned'</script>Power";

/// The dust collector's library profile with a hostile label on `power`, in `dir`.
fn hostile_profile(dir: &std::path::Path) -> PathBuf {
    let library = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/profiles/ruiwan-dust-collector.toml"
    );
    let text = std::fs::read_to_string(library).expect("the library profile");
    let marked = text.replacen(
        "name = \"power\"\n",
        &format!("name = \"power\"\nlabel = \"{HOSTILE_LABEL}\"\n"),
        1,
    );
    assert_ne!(marked, text, "the power field is where the label goes");
    let path = dir.join("dust-collector-labelled.toml");
    std::fs::write(&path, marked).expect("profile written");
    path
}

/// The seed plant's configuration with a console on `port` (with the test's token, or none).
fn console_config(
    broker: &Mosquitto,
    plant: &SeedPlant,
    client_id: &str,
    port: u16,
    token: Option<&str>,
    profile: Option<&std::path::Path>,
) -> String {
    let mut text = PlantConfig {
        gateway: "stats_interval = \"1s\"",
        explicit_serial: true,
        ..PlantConfig::default()
    }
    .text(broker, plant, client_id);
    if let Some(profile) = profile {
        text = text.replacen(
            "profile = \"ruiwan-dust-collector\"",
            &format!("profile = \"{}\"", profile.display()),
            1,
        );
    }
    let token = token.map_or(String::new(), |token| format!("token = \"{token}\"\n"));
    text.push_str(&format!("\n[web]\nlisten = \"127.0.0.1:{port}\"\n{token}"));
    text
}

/// Types `addresses` into the scan form and sends it.
async fn start_scan(form: &support::browser::Element, addresses: &str) {
    let field = form.find(Locator::Css("[name=addresses]")).await.unwrap();
    field.clear().await.unwrap();
    field.send_keys(addresses).await.unwrap();
    form.find(Locator::Css("button[type=submit]"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
}

fn shots() -> (PathBuf, Option<tempfile::TempDir>) {
    match std::env::var_os("RTU2MQTT_SCREENSHOTS") {
        Some(dir) => {
            let dir = PathBuf::from(dir);
            std::fs::create_dir_all(&dir).expect("the screenshot directory");
            (dir, None)
        }
        None => {
            let dir = tempfile::tempdir().expect("a temporary directory");
            (dir.path().to_path_buf(), Some(dir))
        }
    }
}

fn unix_ms() -> f64 {
    SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0.0, |d| d.as_secs_f64() * 1000.0)
}

/// One raw HTTP/1.1 request; the whole answer as text.
async fn http(port: u16, request: &str) -> String {
    let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .expect("the console answers");
    stream.write_all(request.as_bytes()).await.expect("sent");
    let mut answer = Vec::new();
    tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut answer))
        .await
        .expect("answered in time")
        .expect("read");
    String::from_utf8_lossy(&answer).into_owned()
}

fn post(port: u16, path: &str, origin: Option<&str>, cookie: Option<&str>, body: &str) -> String {
    let origin = origin.map_or(String::new(), |o| format!("Origin: {o}\r\n"));
    let cookie = cookie.map_or(String::new(), |c| format!("Cookie: {c}\r\n"));
    format!(
        "POST {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n{origin}{cookie}\
         Content-Type: application/x-www-form-urlencoded\r\nContent-Length: {}\r\n\
         Connection: close\r\n\r\n{body}",
        body.len()
    )
}

/// The session cookie of a login with `token`.
async fn login(port: u16, token: &str) -> Option<String> {
    let origin = format!("http://127.0.0.1:{port}");
    let answer = http(
        port,
        &post(
            port,
            "/login",
            Some(&origin),
            None,
            &format!("token={token}"),
        ),
    )
    .await;
    answer
        .lines()
        .find_map(|line| line.strip_prefix("set-cookie: "))
        .map(|cookie| cookie.split(';').next().unwrap_or("").to_string())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_shows_commands_and_commissions_the_plant_in_a_real_browser() {
    let (shots, _keep) = shots();
    let port = free_port();
    let mut h = PlantBench::setup("console")
        .prepare(|plant| sim::lock(&plant.dust_collector).set_power(true))
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, Some(TOKEN), None)
        })
        .start()
        .await;
    h.wait_text("plant/dust_collector/power", "ON").await;
    let base = format!("http://127.0.0.1:{port}");
    let browser = Browser::start(1280, 1000).await;

    // Every page needs the login: the page itself sends there first.
    browser.goto(&format!("{base}/#/plant")).await;
    let field = browser.wait_for("input[name=token]").await;
    browser.screenshot(&shots.join("login.png")).await;
    field.send_keys(TOKEN).await.unwrap();
    browser
        .wait_for("button[type=submit]")
        .await
        .click()
        .await
        .unwrap();

    // The plant: every value as the broker carries it.
    let valve_position = "[data-topic=\"plant/valve/opening\"]";
    browser.wait_for(valve_position).await;
    for topic in [
        "plant/valve/opening",
        "plant/dust_collector/gear",
        "plant/air_shower/light",
    ] {
        let on_broker = h
            .observer
            .wait_for(topic, support::PLANT_ANSWER, |_| true)
            .await
            .text();
        let css = format!("[data-topic=\"{topic}\"]");
        browser.wait_text(&css, |text| text == on_broker).await;
    }
    // A change on the device reaches the page within one poll and 100 ms.
    browser
        .eval(
            "window.__changed = null; const node = document.querySelector(\
             '[data-topic=\"plant/dust_collector/temperature_alarm\"]');\
             new MutationObserver(() => { if (node.textContent === 'ON' && !window.__changed) \
             window.__changed = Date.now(); }).observe(node, {childList: true, characterData: true, subtree: true});\
             return node.textContent;",
        )
        .await;
    h.observer.forget();
    let changed_at = unix_ms();
    sim::lock(&h.plant.dust_collector).set_alarms(1);
    let on_broker = h
        .observer
        .wait_for_new(
            "plant/dust_collector/temperature_alarm",
            support::PLANT_ANSWER,
            |m| m.text() == "ON",
        )
        .await;
    let broker_at = unix_ms();
    let give_up = Instant::now() + Duration::from_secs(10);
    let shown_at = loop {
        let value = browser.eval("return window.__changed;").await;
        if let Some(at) = value.as_f64() {
            break at;
        }
        assert!(Instant::now() < give_up, "the alarm never reached the page");
        tokio::time::sleep(Duration::from_millis(20)).await;
    };
    assert_eq!(on_broker.text(), "ON");
    let delay = shown_at - changed_at;
    // The test polls at 300 ms, but never faster than the profile allows.
    let profile = rtu2mqtt_profile::registry::built_in("ruiwan-dust-collector").unwrap();
    let poll = (profile.limits().min_poll_interval.as_secs_f64() * 1000.0).max(300.0);
    println!(
        "register change to the page: {delay:.0} ms (to an MQTT subscriber: {:.0} ms; poll \
         interval {poll} ms)",
        broker_at - changed_at
    );
    assert!(
        delay <= poll + 100.0,
        "the page followed a change after {delay:.0} ms"
    );
    assert!(
        shown_at - broker_at <= 100.0,
        "the page showed the change {:.0} ms after an MQTT subscriber",
        shown_at - broker_at
    );
    // Nothing on the page but what it draws: no stray text between the heading and the cards.
    let stray = browser
        .eval(
            "return [...document.getElementById('page').childNodes]\
             .filter((node) => node.nodeType === Node.TEXT_NODE)\
             .map((node) => node.textContent);",
        )
        .await;
    assert_eq!(
        stray,
        serde_json::json!([]),
        "text outside the page's elements"
    );
    browser.screenshot(&shots.join("plant.png")).await;

    // A command from the page: the seed document's golden frame, and its outcome shown.
    browser
        .goto(&format!("{base}/#/device/dust_collector"))
        .await;
    let gear = "[data-command-topic=\"plant/dust_collector/gear/set\"]";
    let input = browser.wait_for(gear).await;
    h.plant.line_a.journal().clear();
    input.send_keys("8\u{E007}").await.unwrap();
    let outcome = "[data-outcome-for=\"plant/dust_collector/gear/set\"]";
    let shown = browser
        .wait_text(outcome, |t| t.starts_with("applied"))
        .await;
    assert!(shown.contains("(8)"), "{shown}");
    let sent: Vec<String> = h
        .plant
        .line_a
        .journal()
        .frames()
        .iter()
        .map(|f| hex::encode(f))
        .collect();
    assert!(
        sent.iter().any(|f| f == "01 06 10 02 00 08 2D 0C"),
        "the golden frame was not sent: {sent:#?}"
    );
    assert_eq!(sim::lock(&h.plant.dust_collector).gear(), 8);
    let result = h
        .observer
        .wait_for(
            "plant/dust_collector/gear/result",
            support::PLANT_ANSWER,
            |_| true,
        )
        .await
        .json();
    assert_eq!(result["outcome"], "applied", "{result}");

    // A refused command: its reason on the page, nothing on the wire.
    h.plant.line_a.journal().clear();
    let pulse = "[data-command-topic=\"plant/dust_collector/pulse_interval/set\"]";
    browser
        .wait_for(pulse)
        .await
        .send_keys("250\u{E007}")
        .await
        .unwrap();
    let refused = browser
        .wait_text(
            "[data-outcome-for=\"plant/dust_collector/pulse_interval/set\"]",
            |t| t.starts_with("rejected"),
        )
        .await;
    // The same words as the profile's own refusal.
    let dust = rtu2mqtt_profile::registry::built_in("ruiwan-dust-collector").unwrap();
    let Err(rtu2mqtt_profile::Rejection(expected)) = dust.plan_command(
        "pulse_interval",
        "250",
        &rtu2mqtt_profile::DeviceState::new(),
    ) else {
        panic!("pulse_interval=250 accepted");
    };
    assert!(refused.contains(&expected), "{refused} / {expected}");
    tokio::time::sleep(Duration::from_millis(400)).await;
    assert_eq!(
        writes(&h.plant.line_a.journal().frames(), DUST),
        Vec::<String>::new()
    );
    browser.screenshot(&shots.join("device.png")).await;

    // The lines: their figures.
    browser.goto(&format!("{base}/#/lines")).await;
    browser
        .wait_text("[data-line-stats=line-a] [data-figure=transactions]", |t| {
            t.parse::<u64>().is_ok_and(|n| n > 0)
        })
        .await;
    browser.screenshot(&shots.join("lines.png")).await;

    // The frames: the line's requests and answers as the wire carried them.
    browser.goto(&format!("{base}/#/frames")).await;
    let row = browser.wait_for("tr[data-line=line-b][data-hex]").await;
    let hex_text = row.attr("data-hex").await.unwrap().unwrap_or_default();
    assert!(hex_text.starts_with("01"), "{hex_text}");
    assert_eq!(hex_text, hex_text.to_lowercase());
    // A request the valve saw, or an answer it sent.
    let on_the_wire: Vec<String> = h
        .plant
        .line_b
        .journal()
        .requests()
        .into_iter()
        .flat_map(|record| [Some(record.frame), record.answer])
        .flatten()
        .map(|frame| hex::encode(&frame).replace(' ', "").to_lowercase())
        .collect();
    assert!(
        on_the_wire.contains(&hex_text),
        "{hex_text} is neither a request the valve saw nor an answer it sent"
    );
    browser.screenshot(&shots.join("frames.png")).await;

    // Commissioning through the running line: the scan finds the seed devices while polls go
    // on, and no request comes inside t3.5.
    browser.goto(&format!("{base}/#/commission")).await;
    let scan = browser.wait_for("form[data-form=scan]").await;
    h.plant.line_a.journal().clear();
    let polls_before = h.plant.line_a.journal().request_count();
    start_scan(&scan, "1-5,129").await;
    browser
        .wait_for("#scan-result tr[data-address=\"129\"]")
        .await;
    browser
        .wait_for("#scan-result tr[data-address=\"1\"]")
        .await;
    let found = browser
        .eval("return [...document.querySelectorAll('#scan-result tr[data-address]')].map(r => r.dataset.address);")
        .await;
    assert_eq!(found, serde_json::json!(["1", "129"]));
    let journal = h.plant.line_a.journal();
    // The scan's reads: a probe of one item at address 0, a Read Device Identification, a
    // SunSpec marker or model header (two holding registers). Everything else is the line's
    // own polling.
    let scan_read = |f: &Vec<u8>| {
        f.get(2..6) == Some(&[0, 0, 0, 1][..])
            || f.get(1) == Some(&0x2B)
            || (f.get(1) == Some(&0x03) && f.get(4..6) == Some(&[0, 2][..]))
    };
    let polls = journal.frames().iter().filter(|f| !scan_read(f)).count();
    assert!(
        journal.request_count() > polls_before + 6 && polls > 0,
        "the line's polls stopped during the scan"
    );
    let format = CharFormat {
        data_bits: 8,
        parity: Parity::None,
        stop_bits: 1,
    };
    let t3_5 = LineTiming::new(9600, format).t3_5;
    let min_silence = journal.min_silence().expect("requests on the line");
    assert!(
        min_silence >= t3_5,
        "a request {min_silence:?} after the last frame"
    );

    // A profile tried against the dust collector: its fields decoded as the gateway publishes.
    let tryout = browser.wait_for("form[data-form=tryout]").await;
    let profile_text = std::fs::read_to_string(concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/config/profiles/ruiwan-dust-collector.toml"
    ))
    .unwrap();
    browser
        .client
        .execute(
            "document.querySelector('form[data-form=tryout] [name=profile]').value = arguments[0];",
            vec![serde_json::Value::String(profile_text)],
        )
        .await
        .unwrap();
    tryout
        .find(Locator::Css("button[type=submit]"))
        .await
        .unwrap()
        .click()
        .await
        .unwrap();
    let gear_shown = browser
        .wait_text("#tryout-result tr[data-field=gear] .value", |t| {
            !t.is_empty()
        })
        .await;
    assert_eq!(gear_shown, "8");
    let power_shown = browser
        .wait_text("#tryout-result tr[data-field=power] .value", |t| {
            !t.is_empty()
        })
        .await;
    assert_eq!(power_shown, "ON");
    browser
        .eval("document.querySelector('#tryout-result').scrollIntoView(); return true;")
        .await;
    browser.screenshot(&shots.join("commission.png")).await;

    // The gateway: connected, with the configuration and no secret.
    browser.goto(&format!("{base}/#/gateway")).await;
    let config_shown = browser
        .wait_text("#effective-config", |t| t.contains("\"prefix\""))
        .await;
    assert!(
        !config_shown.contains(TOKEN),
        "the token reached the browser"
    );
    browser.screenshot(&shots.join("gateway.png")).await;

    // At a phone's width.
    browser.client.set_window_size(390, 844).await.unwrap();
    browser.goto(&format!("{base}/#/device/valve")).await;
    browser
        .wait_for("[data-topic=\"plant/valve/opening\"]")
        .await;
    tokio::time::sleep(Duration::from_millis(300)).await;
    browser.screenshot(&shots.join("phone.png")).await;
    browser.close().await;
    h.stop().await;
}

/// The seed plant with two more devices on line A, which the configuration does not have: a
/// SunSpec inverter at 3 and an iEM3155 meter at 4, which answers Read Device Identification.
fn plant_with_newcomers() -> SeedPlant {
    use rtu2mqtt_sim::{share, ServeOptions, VirtualLine};
    let (dust_collector, dust) = share(sim::DustCollector::new(1));
    let (air_shower, shower) = share(sim::AirShower::new());
    let (valve, valve_shared) = share(sim::Valve::new(1));
    let inverter = share(sim::library::sunspec_inverter().device(3)).1;
    let meter = share(sim::library::iem3155().device(4)).1;
    let line_a = VirtualLine::spawn(
        ServeOptions::new(9600, Parity::None),
        vec![dust, shower, inverter, meter],
    )
    .expect("line A");
    let line_b = VirtualLine::spawn(ServeOptions::new(9600, Parity::Even), vec![valve_shared])
        .expect("line B");
    SeedPlant {
        line_a,
        line_b,
        dust_collector,
        air_shower,
        valve,
    }
}

/// The console's scan asks each device it finds what it is, through the running line: the
/// table shows what each said and the profile that fits, and the configuration to add holds
/// the two devices the line does not have yet. Only reads reach the line.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_scan_names_what_each_device_is() {
    let (shots, _keep) = shots();
    let port = free_port();
    let mut h = PlantBench::setup("console-identify")
        .plant(plant_with_newcomers)
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, Some(TOKEN), None)
        })
        .start()
        .await;
    h.wait_text("plant/dust_collector/power", "OFF").await;
    let browser = Browser::start(1280, 1000).await;
    browser
        .goto(&format!("http://127.0.0.1:{port}/login"))
        .await;
    let field = browser.wait_for("input[name=token]").await;
    field.send_keys(&format!("{TOKEN}\u{E007}")).await.unwrap();
    browser.wait_for("[data-device=dust_collector]").await;
    browser
        .goto(&format!("http://127.0.0.1:{port}/#/commission"))
        .await;
    let scan = browser.wait_for("form[data-form=scan]").await;
    h.plant.line_a.journal().clear();
    start_scan(&scan, "1-4,129").await;
    let configuration = browser
        .wait_text("#scan-configuration", |t| !t.is_empty())
        .await;
    let rows = browser
        .eval(
            "return Object.fromEntries([...document.querySelectorAll('#scan-result tr[data-address]')]\
             .map(r => [r.dataset.address, Object.fromEntries([...r.querySelectorAll('[data-identification]')]\
             .map(c => [c.dataset.identification, c.textContent]))]));",
        )
        .await;
    let exception_01 = "exception 01 (illegal function)";
    assert_eq!(
        rows,
        serde_json::json!({
            "1": {"fc43": exception_01, "vendor": "-", "product_code": "-", "revision": "-", "sunspec": "-", "profile": "unknown"},
            "3": {"fc43": exception_01, "vendor": "-", "product_code": "-", "revision": "-", "sunspec": "40000: models 1, 103, 160", "profile": "sunspec-inverter"},
            "4": {"fc43": "ok", "vendor": "Schneider Electric", "product_code": "A9MEM3155", "revision": "002.001.004", "sunspec": "-", "profile": "schneider-iem3155"},
            "129": {"fc43": exception_01, "vendor": "-", "product_code": "-", "revision": "-", "sunspec": "-", "profile": "unknown"},
        })
    );
    // The page's text, as the browser gives it, without the last line end.
    assert_eq!(
        configuration,
        "# under the [[lines]] table of \"line-a\":\n\n\
         [[lines.devices]]\nname = \"sunspec_inverter_3\"\nprofile = \"sunspec-inverter\"\naddress = 3\n\n\
         [[lines.devices]]\nname = \"schneider_iem3155_4\"\nprofile = \"schneider-iem3155\"\naddress = 4"
    );
    browser
        .eval(
            "const top = document.querySelector('form[data-form=scan]').getBoundingClientRect().top;\
             window.scrollBy(0, top - 70); return true;",
        )
        .await;
    browser.screenshot(&shots.join("scan.png")).await;
    browser.close().await;
    // The meter at 4 was asked for its identification, and nothing but reads reached line A.
    let frames = h.plant.line_a.journal().frames();
    assert!(
        frames
            .iter()
            .any(|f| f.starts_with(&[4, 0x2B, 0x0E, 0x01, 0x00])),
        "{frames:02X?}"
    );
    for frame in &frames {
        assert!(
            (1..=4).contains(&frame[1]) || frame.get(1..3) == Some(&[0x2B, 0x0E][..]),
            "a frame other than a read: {frame:02X?}"
        );
    }
    h.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn without_a_session_or_from_another_origin_nothing_changes() {
    let profiles = tempfile::tempdir().unwrap();
    let labelled = hostile_profile(profiles.path());
    let port = free_port();
    let mut h = PlantBench::setup("console-guard")
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, Some(TOKEN), Some(&labelled))
        })
        .start()
        .await;
    h.wait_text("plant/dust_collector/power", "OFF").await;
    let origin = format!("http://127.0.0.1:{port}");

    // A label with markup in it is text: shown as written, never run.
    let browser = Browser::start(1024, 768).await;
    browser.goto(&format!("{origin}/login")).await;
    let field = browser.wait_for("input[name=token]").await;
    field.send_keys(&format!("{TOKEN}\u{E007}")).await.unwrap();
    let label = browser
        .wait_text(
            "[data-device=dust_collector] tr[data-field=power] th",
            |t| !t.is_empty(),
        )
        .await;
    assert_eq!(label, HOSTILE_LABEL);
    browser
        .wait_text("[data-topic=\"plant/dust_collector/power\"]", |t| {
            t == "OFF"
        })
        .await;
    let title = browser.eval("return document.title;").await;
    assert_eq!(title, "rtu2mqtt console", "a label's script ran");
    browser.close().await;
    let command = "topic=plant%2Fdust_collector%2Fpower%2Fset&payload=ON";
    h.plant.line_a.journal().clear();

    // No session: refused, and a page is sent to the login.
    let answer = http(
        port,
        &post(port, "/api/command", Some(&origin), None, command),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 401"), "{answer}");
    let page = http(
        port,
        &format!("GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"),
    )
    .await;
    assert!(
        page.starts_with("HTTP/1.1 303") && page.contains("location: /login"),
        "{page}"
    );
    // A wrong token: no session.
    assert_eq!(login(port, "not-the-console-token").await, None);
    // The right one from another site's page: refused.
    let answer = http(
        port,
        &post(
            port,
            "/login",
            Some("http://evil.example"),
            None,
            &format!("token={TOKEN}"),
        ),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 403"), "{answer}");

    let cookie = login(port, TOKEN).await.expect("a session for the token");
    let answer = http(port, &format!("GET /api/model HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nCookie: {cookie}\r\nConnection: close\r\n\r\n")).await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    // A session, but the request comes from another origin (or says none): refused.
    for origin in [Some("http://evil.example"), None] {
        let answer = http(
            port,
            &post(port, "/api/command", origin, Some(&cookie), command),
        )
        .await;
        assert!(answer.starts_with("HTTP/1.1 403"), "{answer}");
    }
    // Bad requests get a 4xx, never a crash.
    for body in [
        "topic=plant%2Fnope&payload=1",
        "payload=1",
        "%%%",
        "topic=plant%2Fdust_collector%2Fpower%2Fset&payload=",
    ] {
        let answer = http(
            port,
            &post(port, "/api/command", Some(&origin), Some(&cookie), body),
        )
        .await;
        assert!(answer.starts_with("HTTP/1.1 4"), "{body}: {answer}");
    }
    let huge = "x".repeat(rtu2mqtt::web::MAX_BODY + 1);
    let answer = http(
        port,
        &post(port, "/api/tryout", Some(&origin), Some(&cookie), &huge),
    )
    .await;
    assert!(
        answer.starts_with("HTTP/1.1 413"),
        "{}",
        &answer[..answer.len().min(200)]
    );
    tokio::time::sleep(Duration::from_millis(500)).await;
    assert_eq!(
        writes(&h.plant.line_a.journal().frames(), DUST),
        Vec::<String>::new()
    );

    // With the session and the console's own origin, the command runs.
    let answer = http(
        port,
        &post(port, "/api/command", Some(&origin), Some(&cookie), command),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 202"), "{answer}");
    let result = h.result("dust_collector", "power").await;
    assert_eq!(result["outcome"], "applied", "{result}");
    h.stop().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_console_without_a_token_only_reads_and_slow_clients_stall_nothing() {
    let port = free_port();
    let mut h = PlantBench::setup("console-read-only")
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, None, None)
        })
        .start()
        .await;
    let origin = format!("http://127.0.0.1:{port}");
    h.plant.line_a.journal().clear();
    let command = "topic=plant%2Fdust_collector%2Fpower%2Fset&payload=ON";
    let answer = http(
        port,
        &post(port, "/api/command", Some(&origin), None, command),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 403"), "{answer}");
    assert!(answer.contains("only reads"), "{answer}");

    // Ten clients that open a connection and send half a request, and never finish it.
    let mut slow = Vec::new();
    for _ in 0..10 {
        let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .unwrap();
        stream
            .write_all(b"GET /api/model HTTP/1.1\r\nHost: x")
            .await
            .unwrap();
        slow.push(stream);
    }
    // Ten more that read an event stream and never take what it sends.
    for _ in 0..10 {
        let mut stream = tokio::net::TcpStream::connect(("127.0.0.1", port))
            .await
            .unwrap();
        let request = format!("GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n");
        stream.write_all(request.as_bytes()).await.unwrap();
        slow.push(stream);
    }
    // The page, the plant and the broker go on.
    let started = Instant::now();
    let answer = http(
        port,
        &format!("GET /api/model HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"),
    )
    .await;
    assert!(answer.starts_with("HTTP/1.1 200"), "{answer}");
    assert!(
        started.elapsed() < Duration::from_secs(2),
        "{:?}",
        started.elapsed()
    );
    sim::lock(&h.plant.valve).set_opening(42);
    h.wait_new_text("plant/valve/opening", "42").await;
    assert_eq!(
        writes(&h.plant.line_a.journal().frames(), DUST),
        Vec::<String>::new()
    );
    drop(slow);
    h.stop().await;
}

/// A self-signed certificate for 127.0.0.1 in `dir`: (certificate, key).
fn self_signed(dir: &std::path::Path) -> (PathBuf, PathBuf) {
    let (cert, key) = (dir.join("console.crt"), dir.join("console.key"));
    let status = std::process::Command::new("openssl")
        .args([
            "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "2", "-subj",
        ])
        .arg("/CN=127.0.0.1")
        .args(["-addext", "subjectAltName=IP:127.0.0.1"])
        // An end entity of its own, not a CA: rustls refuses a CA certificate as a server's.
        .args(["-addext", "basicConstraints=critical,CA:FALSE"])
        .args(["-addext", "extendedKeyUsage=serverAuth", "-keyout"])
        .arg(&key)
        .arg("-out")
        .arg(&cert)
        .stderr(std::process::Stdio::null())
        .status()
        .expect("openssl runs");
    assert!(status.success(), "openssl made no certificate");
    (cert, key)
}

/// One HTTPS request trusting `cert`; the whole answer as text.
async fn https(port: u16, cert: &std::path::Path, request: &str) -> String {
    use rustls::pki_types::pem::PemObject;
    use rustls::pki_types::{CertificateDer, ServerName};
    let mut roots = rustls::RootCertStore::empty();
    for der in CertificateDer::pem_file_iter(cert).unwrap() {
        roots.add(der.unwrap()).unwrap();
    }
    let provider = std::sync::Arc::new(rustls::crypto::ring::default_provider());
    let config = rustls::ClientConfig::builder_with_provider(provider)
        .with_safe_default_protocol_versions()
        .unwrap()
        .with_root_certificates(roots)
        .with_no_client_auth();
    let connector = tokio_rustls::TlsConnector::from(std::sync::Arc::new(config));
    let tcp = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .unwrap();
    let name = ServerName::try_from("127.0.0.1").unwrap();
    let mut stream = connector.connect(name, tcp).await.expect("a TLS session");
    stream.write_all(request.as_bytes()).await.unwrap();
    let mut answer = Vec::new();
    let _ = tokio::time::timeout(Duration::from_secs(10), stream.read_to_end(&mut answer)).await;
    String::from_utf8_lossy(&answer).into_owned()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_speaks_https_with_the_certificate_given() {
    let certs = tempfile::tempdir().unwrap();
    let (cert, key) = self_signed(certs.path());
    let port = free_port();
    let tls_keys = format!(
        "cert_file = \"{}\"\nkey_file = \"{}\"\n",
        cert.display(),
        key.display()
    );
    let h = PlantBench::setup("console-tls")
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, Some(TOKEN), None) + &tls_keys
        })
        .start()
        .await;
    let model = https(
        port,
        &cert,
        &format!(
            "GET /api/model HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\
             Authorization: Bearer {TOKEN}\r\nConnection: close\r\n\r\n"
        ),
    )
    .await;
    assert!(model.starts_with("HTTP/1.1 200"), "{model}");
    assert!(model.contains("\"dust_collector\""), "{model}");
    // The session cookie is Secure over HTTPS, and the origin is https://.
    let login = https(
        port,
        &cert,
        &post(
            port,
            "/login",
            Some(&format!("https://127.0.0.1:{port}")),
            None,
            &format!("token={TOKEN}"),
        ),
    )
    .await;
    let cookie = login
        .lines()
        .find(|line| line.starts_with("set-cookie: "))
        .unwrap_or_else(|| panic!("no session: {login}"));
    assert!(
        cookie.contains("HttpOnly")
            && cookie.contains("SameSite=Strict")
            && cookie.contains("Secure"),
        "{cookie}"
    );
    // Plain HTTP on the HTTPS port gets no page.
    let plain = http(
        port,
        &format!("GET /api/model HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n\r\n"),
    )
    .await;
    assert!(!plain.contains("dust_collector"), "{plain}");
    h.stop().await;
}

/// A GET with the bearer token; the whole answer.
async fn get(port: u16, path: &str) -> String {
    http(
        port,
        &format!(
            "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nAuthorization: Bearer {TOKEN}\r\n\
             Connection: close\r\n\r\n"
        ),
    )
    .await
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_console_follows_a_reload() {
    let port = free_port();
    let h = PlantBench::setup("console-reload")
        .config(move |broker, plant, client_id| {
            console_config(broker, plant, client_id, port, Some(TOKEN), None)
        })
        .reloadable()
        .start()
        .await;
    let model = get(port, "/api/model").await;
    assert!(model.contains("\"valve\""), "{model}");
    // The event stream a page holds, to see it told.
    let mut events = tokio::net::TcpStream::connect(("127.0.0.1", port))
        .await
        .unwrap();
    let request = format!(
        "GET /api/events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nAuthorization: Bearer {TOKEN}\r\n\r\n"
    );
    events.write_all(request.as_bytes()).await.unwrap();

    // line-b and its valve go; line-a is restarted with the dust collector alone.
    let text = h.config_text.clone();
    let without_b = text
        .split("\n[[lines]]\nname = \"line-b\"")
        .next()
        .unwrap()
        .to_string();
    let cut_shower = without_b.replacen(
        "\n[[lines.devices]]\nname = \"air_shower\"\nprofile = \"lixian-air-shower\"\naddress = 0x81\n",
        "\n",
        1,
    );
    assert_ne!(
        cut_shower, without_b,
        "the air shower's table is where it is expected"
    );
    let web = text[text.find("\n[web]").unwrap()..].to_string();
    let (reload, dir) = h.reload.as_ref().unwrap();
    std::fs::write(dir.path().join("rtu2mqtt.toml"), cut_shower + &web).unwrap();
    reload.send(()).await.unwrap();

    let give_up = Instant::now() + Duration::from_secs(15);
    loop {
        let model = get(port, "/api/model").await;
        if !model.contains("\"valve\"") && !model.contains("\"air_shower\"") {
            assert!(model.contains("\"dust_collector\""), "{model}");
            break;
        }
        assert!(
            Instant::now() < give_up,
            "the console kept the old plant: {model}"
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let mut seen = Vec::new();
    let give_up = Instant::now() + Duration::from_secs(10);
    while !String::from_utf8_lossy(&seen).contains("event: layout") {
        let mut buffer = [0u8; 4096];
        let read = tokio::time::timeout(Duration::from_secs(1), events.read(&mut buffer)).await;
        if let Ok(Ok(read)) = read {
            seen.extend_from_slice(&buffer[..read]);
        }
        assert!(
            Instant::now() < give_up,
            "the page was not told of the reload"
        );
    }
    // Commissioning goes through the new line task.
    let origin = format!("http://127.0.0.1:{port}");
    let cookie = login(port, TOKEN).await.unwrap();
    let read = http(
        port,
        &post(
            port,
            "/api/read",
            Some(&origin),
            Some(&cookie),
            "line=line-a&address=1&function=3&start=0x1000&count=6",
        ),
    )
    .await;
    assert!(read.starts_with("HTTP/1.1 200"), "{read}");
    assert!(read.contains("\"registers\""), "{read}");
    let gone = http(
        port,
        &post(
            port,
            "/api/scan",
            Some(&origin),
            Some(&cookie),
            "line=line-b&addresses=1",
        ),
    )
    .await;
    assert!(gone.starts_with("HTTP/1.1 404"), "{gone}");
    h.stop().await;
}

//! `dvnav serve`, the DVST controller service, as a robot sees it: a real server process with
//! the shipped meta agent (`models/meta-r0.2`) on port 0, called over gRPC. Commands are those
//! of the meta agent through DVST, bit for bit; malformed requests get INVALID_ARGUMENT naming
//! the field; a new footprint changes μ; with a token, calls without it are UNAUTHENTICATED;
//! over TLS, only clients that trust the server's CA are answered; SIGTERM stops the server
//! cleanly.

use dvnav_nav::dvst::{Dvst, VariedRobot};
use dvnav_nav::policy::{MetaAgent, NavPolicy};
use dvnav_proto::controller::v1::controller_client::ControllerClient;
use dvnav_proto::controller::v1::{
    ActRequest, InfoRequest, LaserScan, Pose2D, SetFootprintRequest, SetRouteRequest,
};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};
use support::KillOnDrop;
use tonic::Code;
use tonic::transport::Channel;

mod support;

fn repo(path: &str) -> PathBuf {
    Path::new(env!("CARGO_MANIFEST_DIR")).join(path)
}

/// A `dvnav serve` process, killed if a test fails before stopping it.
struct Server {
    child: KillOnDrop,
    log: PathBuf,
    url: String,
}

impl Server {
    /// `dvnav serve` with the shipped meta agent.
    fn start(dir: &Path, footprint: &str, extra: &[&str]) -> Server {
        Server::start_with("models/meta-r0.2", dir, footprint, extra)
    }

    fn start_with(model: &str, dir: &Path, footprint: &str, extra: &[&str]) -> Server {
        let addr_file = dir.join("addr");
        let log = dir.join("serve.log");
        let child = Command::new(env!("CARGO_BIN_EXE_dvnav"))
            .args(["serve", "--listen", "127.0.0.1:0", "--checkpoint"])
            .arg(repo(model))
            .arg("--footprint")
            .arg(repo(footprint))
            .arg("--addr-file")
            .arg(&addr_file)
            .args(extra)
            .env("RUST_LOG", "info")
            .env_remove("DVNAV_TOKEN")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(&log).unwrap())
            .spawn()
            .unwrap();
        let mut server = Server { child: KillOnDrop(child), log, url: String::new() };
        let deadline = Instant::now() + Duration::from_secs(60);
        while !addr_file.exists() {
            if let Some(st) = server.child.try_wait().unwrap() {
                panic!("dvnav serve exited with {st}: {}", server.log());
            }
            assert!(Instant::now() < deadline, "no address file: {}", server.log());
            std::thread::sleep(Duration::from_millis(20));
        }
        server.url = format!("http://{}", std::fs::read_to_string(&addr_file).unwrap());
        server
    }

    fn log(&self) -> String {
        std::fs::read_to_string(&self.log).unwrap_or_default()
    }

    async fn client(&self) -> ControllerClient<Channel> {
        ControllerClient::connect(self.url.clone()).await.unwrap()
    }

    fn terminate(&self) {
        // SAFETY: signals a child this test started and still owns.
        unsafe { libc::kill(self.child.id() as i32, libc::SIGTERM) };
    }

    fn exited(&mut self, deadline: Instant) -> Option<(std::process::ExitStatus, String)> {
        let st = self.child.try_wait().unwrap();
        assert!(st.is_some() || Instant::now() < deadline, "still running: {}", self.log());
        st.map(|st| (st, self.log()))
    }

    /// SIGTERM, then the exit status and the log. Async, so that the test's runtime goes on
    /// driving the clients' connections while the server closes them.
    async fn stop(mut self) -> (std::process::ExitStatus, String) {
        self.terminate();
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(done) = self.exited(deadline) {
                return done;
            }
            tokio::time::sleep(Duration::from_millis(20)).await;
        }
    }

    /// SIGTERM while this thread blocks: its clients' connections stay open, unanswered.
    fn stop_blocking(mut self) -> (std::process::ExitStatus, String) {
        self.terminate();
        let deadline = Instant::now() + Duration::from_secs(30);
        loop {
            if let Some(done) = self.exited(deadline) {
                return done;
            }
            std::thread::sleep(Duration::from_millis(20));
        }
    }
}

/// The k-th observation of a robot moving through a room: a varying scan, goal and velocity.
fn request(k: usize) -> ActRequest {
    ActRequest {
        scan: (0..540).map(|i| 0.3 + 4.0 * (1.0 + ((i + 11 * k) as f32 * 0.04).sin())).collect(),
        goal_distance: 0.4 + 0.3 * k as f64,
        goal_angle: -1.2 + 0.25 * k as f64,
        v: 0.05 * k as f64,
        omega: 0.2 - 0.04 * k as f64,
        robot_id: "test-robot".into(),
        ..ActRequest::default()
    }
}

fn invalid(e: tonic::Status, field: &str) {
    assert_eq!(e.code(), Code::InvalidArgument, "{e:?}");
    assert!(e.message().starts_with(&format!("`{field}`: ")), "{e:?}");
}

#[tokio::test]
async fn a_robot_drives_through_the_service_and_changes_its_footprint() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path(), "footprints/small-0.15.toml", &[]);
    let mut client = server.client().await;

    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert_eq!(info.scan_beams, 540);
    assert_eq!((info.scan_fov_deg, info.range_min, info.range_max), (270.0, 0.02, 10.0));
    assert!((info.mu - 0.75).abs() < 1e-12, "{info:?}");
    assert_eq!((info.footprint.as_str(), info.footprint_version), ("small r=0.15", 1));
    assert_eq!(
        (info.model.as_str(), info.meta_robot.as_str()),
        ("meta-r0.2", "circle r = 0.200 m")
    );
    assert!(info.model_version.starts_with("fnv1a64:"), "{info:?}");
    assert_eq!((info.v_max, info.control_period_s), (0.5, 0.2));
    // The shipped agent was trained without the rotation shim, and turns towards a subgoal
    // behind it by itself; its config turns the shim on for deployment all the same, because it
    // takes big robots through tight passages more often (docs/results.md, "The rotation shim
    // for the generalist").
    assert!(info.rotation_shim, "{info:?}");

    // The same meta agent wrapped in DVST in this process answers the same, bit for bit.
    let (agent, _) = MetaAgent::load(&repo("models/meta-r0.2")).unwrap();
    let robot = VariedRobot::load(&repo("footprints/small-0.15.toml")).unwrap();
    let mut direct = Dvst::new(agent, robot).unwrap().with_scan_range(Some([0.02, 10.0])).unwrap();
    for k in 0..10 {
        let r = request(k);
        let mut obs = r.scan.clone();
        obs.extend([r.goal_distance, r.goal_angle, r.v, r.omega].map(|x| x as f32));
        let want = direct.act(&obs).unwrap();
        let got = client.act(r).await.unwrap().into_inner();
        assert_eq!((got.v, got.omega), want, "call {k}");
        assert_eq!((got.mu, got.footprint_version), (info.mu, 1));
        assert_eq!(got.model_version, info.model_version);
        assert!(got.v.abs() <= 0.5 && got.omega.abs() <= info.omega_max, "{got:?}");
    }

    // Malformed requests: the field is named, nothing is answered.
    let short = ActRequest { scan: vec![1.0; 539], ..request(0) };
    let e = client.act(short).await.unwrap_err();
    invalid(e.clone(), "scan");
    assert!(e.message().contains("539 ranges") && e.message().contains("540 beams"), "{e:?}");
    let mut nan = request(1);
    nan.scan[5] = f32::NAN;
    invalid(client.act(nan).await.unwrap_err(), "scan[5]");
    let mut inf = request(1);
    inf.scan[539] = f32::INFINITY;
    invalid(client.act(inf).await.unwrap_err(), "scan[539]");
    let e = client.act(ActRequest { goal_distance: f64::NAN, ..request(2) }).await.unwrap_err();
    invalid(e, "goal_distance");
    let e = client.act(ActRequest { omega: f64::INFINITY, ..request(2) }).await.unwrap_err();
    invalid(e, "omega");
    let e = client.act(ActRequest { scan_age_s: 5.0, ..request(2) }).await.unwrap_err();
    invalid(e, "scan_age_s");
    // A scan 0.2 s old is carried forward by what the server sent this robot: a command.
    client.act(ActRequest { scan_age_s: 0.2, ..request(2) }).await.unwrap();

    // It picks up cargo: the 0.5 m circle, μ = 2.5; a bad file changes nothing.
    let text = std::fs::read_to_string(repo("footprints/circle-0.5.toml")).unwrap();
    let set = |footprint_toml: String| SetFootprintRequest {
        footprint_toml,
        robot_id: "test-robot".into(),
    };
    let changed = client.set_footprint(set(text)).await.unwrap().into_inner();
    assert!((changed.mu - 2.5).abs() < 1e-12, "{changed:?}");
    assert_eq!(changed.scaled_robot, "circle r = 0.500 m");
    assert_eq!((changed.footprint.as_str(), changed.footprint_version), ("circle r=0.5", 2));
    let e = client.set_footprint(set("[[parts]]\nshape = \"hexagon\"\n".into())).await.unwrap_err();
    invalid(e.clone(), "footprint_toml");
    // Robots no physical robot could be are refused, the key named: a part centred 1e308 m
    // away, a box of half extents 1e308 m, a margin of 1e300 m (each once gave μ = inf or 5e300,
    // and a robot that read `arrived` wherever its goal was).
    for (toml, key) in [
        ("[[parts]]\nshape = \"circle\"\ncenter = [1e308, 1e308]\nradius = 0.2\n", "parts[0]"),
        (
            "[[parts]]\nshape = \"box\"\ncenter = [0, 0]\nhalf_extents = [1e308, 1e308]\n",
            "parts[0]",
        ),
        (
            "margin = 1e300\n[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.2\n",
            "margin",
        ),
    ] {
        let e = client.set_footprint(set(toml.into())).await.unwrap_err();
        invalid(e.clone(), "footprint_toml");
        assert!(e.message().contains(key) && e.message().contains("20 m"), "{key}: {e:?}");
    }
    assert!(e.message().contains("line 2: unknown variant `hexagon`"), "{e:?}");
    let got = client.act(request(3)).await.unwrap().into_inner();
    assert_eq!((got.mu, got.footprint_version), (changed.mu, 2), "{got:?}");
    assert_eq!(got.footprint, "circle r=0.5");
    let info = client.info(InfoRequest { robot_id: "test-robot".into() }).await.unwrap();
    let info = info.into_inner();
    assert_eq!((info.mu, info.footprint_version), (changed.mu, 2));
    assert!((info.goal_tolerance - 0.5).abs() < 1e-12, "0.2 m scaled by μ = 2.5: {info:?}");
    let other = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert!((other.mu - 0.75).abs() < 1e-12, "another robot: the default: {other:?}");
    assert_eq!(other.footprint_version, 1);

    drop(client);
    let (status, log) = server.stop().await;
    assert!(status.success(), "{status}: {log}");
    for line in [
        "controller listening",
        "footprint=small r=0.15",
        "footprint changed",
        "mu=2.5",
        "controller stopped",
    ] {
        assert!(log.contains(line), "`{line}` not in the log:\n{log}");
    }
    assert!(log.contains("commands=12"), "11 commands before the change, 1 after:\n{log}");
}

#[tokio::test]
async fn with_a_token_calls_without_it_are_unauthenticated() {
    let dir = tempfile::tempdir().unwrap();
    let token_file = dir.path().join("token");
    std::fs::write(&token_file, "s3cret-token\n").unwrap();
    let token = token_file.to_str().unwrap();
    let server =
        Server::start(dir.path(), "footprints/paper-medium.toml", &["--token-file", token]);
    let mut client = server.client().await;

    let e = client.act(request(0)).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let e = client.info(InfoRequest::default()).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let with = |t: &str, r: ActRequest| {
        let mut req = tonic::Request::new(r);
        req.metadata_mut().insert("authorization", t.parse().unwrap());
        req
    };
    let e = client.act(with("Bearer wrong", request(0))).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "{e:?}");
    let e = client.act(with("s3cret-token", request(0))).await.unwrap_err();
    assert_eq!(e.code(), Code::Unauthenticated, "without `Bearer `: {e:?}");
    let mut set = tonic::Request::new(SetFootprintRequest {
        footprint_toml: "[[parts]]\nshape = \"circle\"\ncenter = [0, 0]\nradius = 0.5\n".into(),
        robot_id: String::new(),
    });
    set.metadata_mut().insert("authorization", "Bearer wrong".parse().unwrap());
    assert_eq!(client.set_footprint(set).await.unwrap_err().code(), Code::Unauthenticated);

    // With the token: answered; and a malformed request is still judged on its own.
    let ok = client.act(with("Bearer s3cret-token", request(0))).await.unwrap().into_inner();
    assert!((ok.mu - 1.85).abs() < 1e-12 && ok.footprint_version == 1, "{ok:?}");
    let short = ActRequest { scan: vec![1.0; 10], ..request(0) };
    invalid(client.act(with("Bearer s3cret-token", short)).await.unwrap_err(), "scan");

    drop(client);
    let (status, log) = server.stop().await;
    assert!(status.success(), "{status}: {log}");
    assert!(log.contains("token=true") && log.contains("commands=1"), "{log}");
    assert!(!log.contains("s3cret"), "the token is never logged:\n{log}");
}

/// A robot whose process hangs with its connection open does not keep the server from
/// stopping: after a short grace the server closes the connection and exits.
#[tokio::test]
async fn a_hung_client_does_not_keep_the_server_from_stopping() {
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path(), "footprints/circle-0.5.toml", &[]);
    let mut client = server.client().await;
    assert_eq!(client.info(InfoRequest::default()).await.unwrap().into_inner().scan_beams, 540);
    // From here this test's (single-threaded) runtime no longer drives the connection.
    let t = Instant::now();
    let (status, log) = server.stop_blocking();
    assert!(status.success(), "{status}: {log}");
    assert!(t.elapsed() < Duration::from_secs(10), "took {:?}: {log}", t.elapsed());
    assert!(log.contains("connections still open at shutdown"), "{log}");
    drop(client);
}

/// With `--tls-cert` and `--tls-key` (from `dvnav certs` for 127.0.0.1, an IP address SAN), a
/// client that trusts the CA is answered; a plaintext client and one that trusts another CA
/// are not.
#[tokio::test]
async fn over_tls_a_client_with_the_ca_is_answered_and_a_plaintext_one_is_not() {
    use dvnav_tls::{ClientTlsFiles, endpoint};
    let dir = tempfile::tempdir().unwrap();
    for name in ["certs", "other"] {
        let out = Command::new(env!("CARGO_BIN_EXE_dvnav"))
            .args(["certs", "--host", "127.0.0.1", "--out"])
            .arg(dir.path().join(name))
            .output()
            .unwrap();
        assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    }
    let file = |d: &str, f: &str| dir.path().join(d).join(f).to_str().unwrap().to_string();
    let (cert, key) = (file("certs", "server.pem"), file("certs", "server.key"));
    let server = Server::start(
        dir.path(),
        "footprints/small-0.15.toml",
        &["--tls-cert", &cert, "--tls-key", &key],
    );
    let https = server.url.replacen("http://", "https://", 1);
    let trusting = |ca: String| ClientTlsFiles { ca: Some(ca.into()), ..Default::default() };

    let tls = trusting(file("certs", "ca.pem")).load().unwrap();
    let channel = endpoint(&https, tls.as_ref()).unwrap().connect().await.unwrap();
    let mut client = ControllerClient::new(channel);
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert_eq!((info.scan_beams, info.footprint.as_str()), (540, "small r=0.15"));
    let got = client.act(request(0)).await.unwrap().into_inner();
    assert!(got.v.abs() <= 0.5 && got.footprint_version == 1, "{got:?}");

    // Plaintext: the connection may open, but no call is answered.
    if let Ok(mut plain) = ControllerClient::connect(server.url.clone()).await {
        let e = plain.info(InfoRequest::default()).await.expect_err("a plaintext call is answered");
        assert_ne!(e.code(), Code::Ok);
        let e = plain.act(request(1)).await.expect_err("a plaintext call is answered");
        assert_ne!(e.code(), Code::Ok);
    }
    // Another CA: the handshake fails.
    let other = trusting(file("other", "ca.pem")).load().unwrap();
    let e = endpoint(&https, other.as_ref()).unwrap().connect().await.expect_err("another CA");
    let text = dvnav_tls::error_chain(&e);
    assert!(text.contains("invalid peer certificate: UnknownIssuer"), "{text}");
    // The trusted client is still answered.
    assert_eq!(client.info(InfoRequest::default()).await.unwrap().into_inner().scan_beams, 540);

    drop(client);
    let (status, log) = server.stop().await;
    assert!(status.success(), "{status}: {log}");
    assert!(log.contains("tls=true") && log.contains("commands=1"), "{log}");
}

/// A Hokuyo UTM-30LX's scan as ROS gives it: 1,081 readings 0.25° apart over 270°, some with
/// no return (+inf).
fn hokuyo(k: usize) -> LaserScan {
    let ranges =
        (0..1081)
            .map(|j| {
                if j % 97 == k % 97 {
                    f32::INFINITY
                } else {
                    0.5 + ((j + 5 * k) % 300) as f32 * 0.02
                }
            })
            .collect();
    LaserScan {
        angle_min: -135f64.to_radians(),
        angle_increment: 0.25f64.to_radians(),
        range_min: 0.023,
        range_max: 30.0,
        ranges,
    }
}

fn code(e: tonic::Status, code: Code, says: &str) {
    assert_eq!(e.code(), code, "{e:?}");
    assert!(e.message().contains(says), "`{says}` not in {e:?}");
}

#[tokio::test]
async fn many_robots_send_laser_scans_arrive_and_expire_and_bad_input_is_refused() {
    use dvnav_nav::dvst::DvstController;
    use dvnav_nav::dvst::controller::{ModelId, RobotInput, Scan};
    let dir = tempfile::tempdir().unwrap();
    let extra = ["--max-robots", "2", "--robot-idle-s", "1"];
    let server = Server::start(dir.path(), "footprints/small-0.15.toml", &extra);
    let mut client = server.client().await;
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert!((info.goal_tolerance - 0.15).abs() < 1e-12, "0.2 m at μ = 0.75: {info:?}");
    assert_eq!((info.max_robots, info.robot_idle_s, info.robots), (2, 1.0, 0));
    assert_eq!((info.lidar_x, info.lidar_yaw, info.lidar_uncovered_range), (0.0, 0.0, 0.0));

    // LaserScans: the command is the in-process controller's, bit for bit.
    let (agent, cfg) = MetaAgent::load(&repo("models/meta-r0.2")).unwrap();
    let text = std::fs::read_to_string(repo("footprints/small-0.15.toml")).unwrap();
    let model = ModelId { name: "m".into(), version: "v".into() };
    let local = DvstController::new(agent, &cfg, model, &text, "small", None).unwrap();
    let act = |k: usize, robot: &str| ActRequest {
        laser_scan: Some(hokuyo(k)),
        goal_distance: 1.5,
        goal_angle: 0.3,
        v: 0.1,
        omega: 0.0,
        robot_id: robot.into(),
        ..ActRequest::default()
    };
    for k in 0..5 {
        let r = act(k, "a");
        let l = r.laser_scan.as_ref().unwrap();
        let scan = dvnav_nav::dvst::LaserScan {
            angle_min: l.angle_min,
            angle_increment: l.angle_increment,
            range_min: l.range_min,
            range_max: l.range_max,
            ranges: &l.ranges,
        };
        let input = RobotInput::new(Scan::Laser(scan), 1.5, 0.3, 0.1, 0.0);
        let want = local.act_async(&input).await.unwrap();
        let got = client.act(r).await.unwrap().into_inner();
        assert_eq!((got.v, got.omega), (want.v, want.omega), "call {k}");
        assert_eq!((got.filled_beams, got.arrived), (0, false));
        assert!((got.goal_tolerance - 0.15).abs() < 1e-12);
    }
    // A 180° sensor leaves the meta agent's outer 45° each side unseen, and says so.
    let mut narrow = act(0, "a");
    let l = narrow.laser_scan.as_mut().unwrap();
    l.angle_min = -90f64.to_radians();
    l.ranges.truncate(721);
    assert_eq!(client.act(narrow).await.unwrap().into_inner().filled_beams, 178);

    // Arrival: within the tolerance the robot stops.
    let near = ActRequest { goal_distance: 0.1, ..act(1, "a") };
    let got = client.act(near).await.unwrap().into_inner();
    assert_eq!((got.arrived, got.v, got.omega), (true, 0.0, 0.0), "{got:?}");

    // A second robot with a footprint of its own; the first keeps the default.
    let big = std::fs::read_to_string(repo("footprints/circle-0.5.toml")).unwrap();
    let set = SetFootprintRequest { footprint_toml: big, robot_id: "big".into() };
    let set = client.set_footprint(set).await.unwrap().into_inner();
    assert!((set.mu - 2.5).abs() < 1e-12 && (set.goal_tolerance - 0.5).abs() < 1e-12);
    let b = client.act(act(2, "big")).await.unwrap().into_inner();
    let a = client.act(act(2, "a")).await.unwrap().into_inner();
    assert_eq!((b.mu, b.footprint_version), (set.mu, set.footprint_version));
    assert!((a.mu - 0.75).abs() < 1e-12 && a.footprint_version == 1, "{a:?}");
    assert_eq!(
        client.info(InfoRequest { robot_id: "big".into() }).await.unwrap().into_inner().mu,
        2.5
    );
    assert_eq!(client.info(InfoRequest::default()).await.unwrap().into_inner().robots, 2);

    // A third robot while both are active: RESOURCE_EXHAUSTED.
    let e = client.act(act(3, "third")).await.unwrap_err();
    code(e, Code::ResourceExhausted, "2 robots are active");
    // A robot that expects another footprint than its own: FAILED_PRECONDITION.
    let stale = ActRequest { expected_footprint_version: 1, ..act(3, "big") };
    code(client.act(stale).await.unwrap_err(), Code::FailedPrecondition, "SetFootprint");

    // Silent for the idle time: `big` is forgotten; expecting its footprint it is refused
    // rather than driven as the small default robot, and the third robot finds room.
    tokio::time::sleep(Duration::from_millis(1200)).await;
    let expects = ActRequest { expected_footprint_version: set.footprint_version, ..act(4, "big") };
    code(client.act(expects).await.unwrap_err(), Code::FailedPrecondition, "version 1");
    assert!(client.act(act(4, "third")).await.is_ok());

    // Every other refusal names its field.
    let both = ActRequest { scan: vec![1.0; 540], ..act(5, "a") };
    invalid(client.act(both).await.unwrap_err(), "laser_scan");
    for (r, field) in [
        (ActRequest { goal_distance: 1e39, ..act(5, "a") }, "goal_distance"),
        (ActRequest { v: 1e308, ..act(5, "a") }, "v"),
        (ActRequest { omega: 1e5, ..act(5, "a") }, "omega"),
        (ActRequest { goal_angle: -1e300, ..act(5, "a") }, "goal_angle"),
        (ActRequest { robot_id: "r".repeat(129), ..act(5, "a") }, "robot_id"),
    ] {
        invalid(client.act(r).await.unwrap_err(), field);
    }
    for (change, field) in [
        (
            (|l: &mut LaserScan| l.angle_increment = 0.0) as fn(&mut LaserScan),
            "laser_scan.angle_increment",
        ),
        (|l: &mut LaserScan| l.range_max = 1e39, "laser_scan.range_max"),
        (|l: &mut LaserScan| l.range_min = f64::NAN, "laser_scan.range_min"),
        (|l: &mut LaserScan| l.ranges.clear(), "laser_scan.ranges"),
        (|l: &mut LaserScan| l.angle_increment = 0.02, "laser_scan.angle_increment"),
    ] {
        let mut r = act(6, "a");
        change(r.laser_scan.as_mut().unwrap());
        invalid(client.act(r).await.unwrap_err(), field);
    }
    let long = InfoRequest { robot_id: "r".repeat(129) };
    invalid(client.info(long).await.unwrap_err(), "robot_id");
    let long = SetFootprintRequest { footprint_toml: text.clone(), robot_id: "r".repeat(129) };
    invalid(client.set_footprint(long).await.unwrap_err(), "robot_id");

    drop(client);
    let (status, log) = server.stop().await;
    assert!(status.success(), "{status}: {log}");
}

/// `dvnav serve --safety-horizon S`: Info reports the monitor (and the stall escape), and a
/// robot driving at an
/// obstacle ahead is slowed below what the same agent in DVST commands unmonitored, its ω kept.
/// The scene is the meta robot's (an obstacle 1.2 m ahead within ±10°, the goal 3 m ahead)
/// scaled by this robot's μ = 0.75.
#[tokio::test]
async fn the_collision_monitor_slows_a_served_robot_short_of_an_obstacle() {
    let dir = tempfile::tempdir().unwrap();
    // The stall escape on too (`--escape-after`): Info says so; a first call is never one.
    let flags = ["--safety-horizon", "3", "--escape-after", "2.5"];
    let server = Server::start(dir.path(), "footprints/small-0.15.toml", &flags);
    let mut client = server.client().await;
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert_eq!((info.safety_horizon_s, info.known_tolerance_m), (3.0, 0.1), "{info:?}");
    assert_eq!(info.escape_after_s, 2.5, "{info:?}");
    let mu = info.mu;
    let scan: Vec<f32> =
        (0..540).map(|i| if (250..290).contains(&i) { 1.2 * mu as f32 } else { 7.5 }).collect();
    let act = ActRequest {
        scan,
        goal_distance: 3.0 * mu,
        goal_angle: 0.0,
        robot_id: "r".into(),
        ..ActRequest::default()
    };
    let held = client.act(act.clone()).await.unwrap().into_inner();
    let (agent, _) = MetaAgent::load(&repo("models/meta-r0.2")).unwrap();
    let robot = VariedRobot::load(&repo("footprints/small-0.15.toml")).unwrap();
    let mut direct = Dvst::new(agent, robot).unwrap().with_scan_range(Some([0.02, 10.0])).unwrap();
    let mut obs = act.scan.clone();
    obs.extend([act.goal_distance as f32, 0.0, 0.0, 0.0]);
    let free = direct.act_batch(&obs).unwrap()[0];
    assert!(free.0 > 0.3, "the agent drives on unmonitored: {free:?}");
    assert!(held.v < free.0 - 0.05, "held {held:?} against {free:?}");
    assert!((held.omega - free.1).abs() < 1e-6, "ω kept: {held:?} against {free:?}");
    drop(client);
    let (status, log) = server.stop().await;
    assert!(status.success(), "{status}: {log}");
}

/// A robot with its own planner hands the controller a route (SetRoute) and sends its pose with
/// every Act: the agent is given the lookahead point as its goal (the command is the one the
/// same meta agent gives for that goal), the rotation shim turns a robot facing away, arrival is
/// at the route's goal, and bad routes are refused naming the field, and counted. Served by the
/// paper agent, whose config keeps the rotation shim on.
#[tokio::test]
async fn a_robot_follows_its_own_planners_route() {
    const PAPER: &str = "models/paper-r0.2";
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start_with(PAPER, dir.path(), "footprints/small-0.15.toml", &[]);
    let mut client = server.client().await;
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert!(info.lookahead_m > 0.0 && info.rotation_shim && info.refused == 0, "{info:?}");
    let pose = |x, y, yaw| Some(Pose2D { x, y, yaw });
    let route = |pts: &[[f64; 2]]| SetRouteRequest {
        robot_id: "r".into(),
        poses: pts.iter().map(|p| Pose2D { x: p[0], y: p[1], yaw: 0.0 }).collect(),
        clear: false,
    };
    let set = client.set_route(route(&[[0.0, 0.0], [4.0, 0.0], [4.0, 3.0]])).await.unwrap();
    let set = set.into_inner();
    assert_eq!((set.poses, set.length_m), (3, 7.0));
    assert!((set.lookahead_m - info.lookahead_m * info.mu).abs() < 1e-12, "{set:?}");

    // On a route, an Act without a pose is refused, naming it.
    let act = |k: usize| ActRequest { robot_id: "r".into(), ..request(k) };
    invalid(client.act(act(1)).await.unwrap_err(), "pose");
    invalid(
        client.act(ActRequest { pose: pose(f64::NAN, 0.0, 0.0), ..act(1) }).await.unwrap_err(),
        "pose.x",
    );

    // Facing away: the shim turns it in place, the agent is not asked.
    let r =
        client.act(ActRequest { pose: pose(0.5, 0.0, 3.0), ..act(1) }).await.unwrap().into_inner();
    assert!(r.following_route && r.v == 0.0 && r.omega.abs() == info.omega_max, "{r:?}");
    // Facing along the path: the agent drives to the lookahead point; the goal fields of the
    // request are not read, the subgoal's are.
    let r =
        client.act(ActRequest { pose: pose(0.5, 0.0, 0.0), ..act(2) }).await.unwrap().into_inner();
    let l = set.lookahead_m;
    assert_eq!((r.subgoal_x, r.subgoal_y), (0.5 + l, 0.0), "{r:?}");
    assert!((r.remaining_m - 6.5).abs() < 1e-12 && !r.replan_wanted && !r.arrived, "{r:?}");
    let (agent, _) = MetaAgent::load(&repo(PAPER)).unwrap();
    let robot = VariedRobot::load(&repo("footprints/small-0.15.toml")).unwrap();
    let mut direct = Dvst::new(agent, robot).unwrap().with_scan_range(Some([0.02, 10.0])).unwrap();
    let q = act(2);
    let mut obs = q.scan.clone();
    obs.extend([l, 0.0, q.v, q.omega].map(|x| x as f32));
    assert_eq!((r.v, r.omega), direct.act(&obs).unwrap());
    // Strayed 2 m off the path: a new route is wanted.
    let r =
        client.act(ActRequest { pose: pose(2.0, -2.0, 0.0), ..act(3) }).await.unwrap().into_inner();
    assert!(r.replan_wanted, "{r:?}");
    // At the route's goal (whatever the request's goal_distance says): arrived, stopped.
    let r =
        client.act(ActRequest { pose: pose(4.0, 2.95, 1.5), ..act(4) }).await.unwrap().into_inner();
    assert!(r.arrived && r.v == 0.0 && r.omega == 0.0, "{r:?}");

    // Bad routes name the field; each refusal is counted.
    invalid(client.set_route(route(&[])).await.unwrap_err(), "poses");
    invalid(
        client.set_route(route(&[[0.0, 0.0], [f64::NAN, 1.0]])).await.unwrap_err(),
        "poses[1].x",
    );
    invalid(client.set_route(route(&[[0.0, 1e6]])).await.unwrap_err(), "poses[0].y");
    let too_long = vec![[0.0, 0.0]; 100_001];
    invalid(client.set_route(route(&too_long)).await.unwrap_err(), "poses");
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert_eq!(info.refused, 6, "{info:?}");
    // Cleared: the robot drives to its request's goal again, no pose needed.
    let clear = SetRouteRequest { robot_id: "r".into(), poses: vec![], clear: true };
    client.set_route(clear).await.unwrap();
    let r = client.act(act(5)).await.unwrap().into_inner();
    assert!(!r.following_route, "{r:?}");
    let (status, _) = server.stop().await;
    assert!(status.success());
}

/// A 5 x 3 m map (0.05 m cells) walled round, split at x = 2.5 m by a wall with a 1 m door at
/// the top: a map_server YAML and a PGM, as a robot's map arrives.
fn door_map() -> (String, Vec<u8>) {
    let (w, h) = (100usize, 60usize);
    let mut px = vec![254u8; w * h];
    for row in 0..h {
        for col in 0..w {
            // Rows count from the top; y = (h - row - 0.5) * 0.05.
            let y = (h - row) as f64 * 0.05 - 0.025;
            let border = row < 2 || row >= h - 2 || col < 2 || col >= w - 2;
            let wall = (49..=51).contains(&col) && !(1.8..2.8).contains(&y);
            if border || wall {
                px[row * w + col] = 0;
            }
        }
    }
    let mut pgm = format!("P5\n{w} {h}\n255\n").into_bytes();
    pgm.extend(px);
    let yaml = "image: door.pgm\nresolution: 0.05\norigin: [0.0, 0.0, 0.0]\nnegate: 0\n\
                occupied_thresh: 0.65\nfree_thresh: 0.196\n";
    (yaml.to_string(), pgm)
}

/// A robot without a planner of its own: the server is given the map (SetMap) and the goal
/// (SetGoal), plans for the robot's footprint and drives it by subgoals; bad maps and goals are
/// refused naming the field.
#[tokio::test]
async fn the_server_plans_on_a_map_for_a_robots_goal() {
    use dvnav_proto::controller::v1::{SetGoalRequest, SetMapRequest};
    let dir = tempfile::tempdir().unwrap();
    let server = Server::start(dir.path(), "footprints/small-0.15.toml", &[]);
    let mut client = server.client().await;
    let p = |x, y| Some(Pose2D { x, y, yaw: 0.0 });
    let goal = |start, goal| SetGoalRequest { robot_id: "r".into(), start, goal };
    // No map yet.
    let e = client.set_goal(goal(p(1.0, 1.0), p(4.0, 1.0))).await.unwrap_err();
    assert_eq!(e.code(), Code::FailedPrecondition, "{e:?}");
    let (yaml, pgm) = door_map();
    let bad = SetMapRequest { map_yaml: yaml.clone(), image: pgm[..50].to_vec() };
    invalid(client.set_map(bad).await.unwrap_err(), "image");
    let bad = SetMapRequest { map_yaml: "resolution: -1\n".into(), image: pgm.clone() };
    invalid(client.set_map(bad).await.unwrap_err(), "map_yaml");
    let set = SetMapRequest { map_yaml: yaml, image: pgm };
    let map = client.set_map(set).await.unwrap().into_inner();
    assert_eq!((map.width, map.height, map.resolution), (100, 60, 0.05));

    // From the left room to the right one: the path goes up through the door.
    let route = client.set_goal(goal(p(1.0, 1.0), p(4.0, 1.0))).await.unwrap().into_inner();
    assert!(route.length_m > 3.0 + 1.0, "{route:?}");
    let act = ActRequest { robot_id: "r".into(), pose: p(1.0, 1.0), ..request(1) };
    let r = client.act(act).await.unwrap().into_inner();
    assert!(r.following_route && !r.blocked && r.replans == 0, "{r:?}");
    assert!(r.subgoal_y > 1.0 && r.subgoal_x < 2.5, "heads for the door: {r:?}");
    assert!(r.remaining_m > 4.0, "{r:?}");
    // Far off its path, the server replans itself, on its planner thread: no replan is asked
    // of the robot, and this call does not wait for it.
    let act = ActRequest { robot_id: "r".into(), pose: p(0.3, 0.3), ..request(2) };
    let r = client.act(act.clone()).await.unwrap().into_inner();
    assert!(r.replanning && r.replans == 0 && !r.replan_wanted && !r.blocked, "{r:?}");
    // A later call takes up the new path.
    let mut later = r;
    for _ in 0..100 {
        tokio::time::sleep(std::time::Duration::from_millis(20)).await;
        later = client.act(act.clone()).await.unwrap().into_inner();
        if later.replans > 0 {
            break;
        }
    }
    let r = later;
    assert!(r.replans == 1 && !r.replanning && !r.replan_wanted && !r.blocked, "{r:?}");
    assert!(r.remaining_m > route.length_m, "planned again from farther away: {r:?}");

    // Off the map, inside a wall, not a number: refused naming the point.
    invalid(client.set_goal(goal(p(1.0, 1.0), p(9.0, 1.0))).await.unwrap_err(), "goal");
    invalid(client.set_goal(goal(p(1.0, 1.0), p(2.5, 1.0))).await.unwrap_err(), "goal");
    invalid(client.set_goal(goal(p(f64::NAN, 1.0), p(4.0, 1.0))).await.unwrap_err(), "start.x");
    invalid(client.set_goal(goal(None, p(4.0, 1.0))).await.unwrap_err(), "start");
    let info = client.info(InfoRequest::default()).await.unwrap().into_inner();
    assert_eq!(info.refused, 6, "{info:?}");
    let (status, _) = server.stop().await;
    assert!(status.success());
}

/// `dvnav bench serve`'s routed fleet really routes: robots on the Willow Garage map follow
/// planned legs, the server replans for the ones that stray, and the figures say so; with the
/// collision monitor on, as `dvnav serve --safety-horizon` runs it.
#[test]
fn the_serve_bench_routes_and_replans_its_robots() {
    let out = Command::new(env!("CARGO_BIN_EXE_dvnav"))
        .args(["bench", "serve", "--calls", "100", "--robots", "2", "--seconds", "2"])
        .args(["--stray-every", "5", "--safety-horizon", "0.6", "--json"])
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .unwrap();
    assert!(out.status.success(), "{}", String::from_utf8_lossy(&out.stderr));
    let r: serde_json::Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(r["route_map"], "maps/willow.yaml", "{r}");
    assert_eq!(r["safety_horizon_s"], 0.6, "{r}");
    let calls = r["route_calls"].as_u64().unwrap();
    // 2 robots at 10 Hz for 2 timed seconds, a stray every 5th call.
    assert!(calls >= 20, "{r}");
    let replans = r["route_replans"].as_u64().unwrap();
    assert!(replans >= 2 && replans <= calls, "{r}");
    // One replan per straying call, each counted once; a replan asked in a robot's last timed
    // call may land after the timing ends.
    let asked = r["route_replan_calls"].as_u64().unwrap();
    assert!(replans <= asked && asked <= replans + 2, "{r}");
    assert!(
        r["route_replan_max_ms"].as_f64().unwrap() >= r["route_replan_p50_ms"].as_f64().unwrap()
    );
}

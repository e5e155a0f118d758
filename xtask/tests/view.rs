//! `xtask view`: bad options refused in one sentence, and a viewer that starts on a free port,
//! answers, stops on SIGTERM and leaves the run folder byte for byte as it was.

use std::io::{BufRead, Read, Write};
use std::process::{Command, Stdio};

fn xtask() -> Command {
    let mut c = Command::new(env!("CARGO_BIN_EXE_xtask"));
    c.stdin(Stdio::null()).stdout(Stdio::piped()).stderr(Stdio::piped());
    c
}

fn refused(args: &[&str], want: &str) {
    let o = xtask().args(args).output().unwrap();
    let err = String::from_utf8_lossy(&o.stderr);
    assert_eq!(o.status.code(), Some(1), "{args:?}: {err}");
    assert!(err.contains(want), "{args:?}: {err}");
    assert_eq!(err.trim().lines().count(), 1, "{args:?}: {err}");
}

#[test]
fn view_refuses_a_missing_folder_no_threads_and_a_taken_port() {
    let tmp = tempfile::tempdir().unwrap();
    let run = tmp.path().to_str().unwrap();
    refused(&["view", "/nonexistent/run"], "/nonexistent/run: not a folder");
    refused(&["view", run, "--threads", "0"], "--threads 0");
    let taken = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = taken.local_addr().unwrap().port().to_string();
    refused(&["view", run, "--port", &port], &format!("cannot listen on 127.0.0.1:{port}"));
}

#[test]
fn view_serves_a_run_and_stops_on_sigterm_without_writing() {
    let tmp = tempfile::tempdir().unwrap();
    let config = test_support::training::write_cli_config(tmp.path(), 4, 4);
    let run = tmp.path().join("run");
    let o = xtask().args(["train".as_ref(), "--config".as_ref(), config.as_os_str(), "--out".as_ref(), run.as_os_str()]).output().unwrap();
    assert!(o.status.success(), "{}", String::from_utf8_lossy(&o.stderr));
    let before = test_support::file_map(&run);
    let mut child = xtask().args(["view".as_ref(), run.as_os_str(), "--port".as_ref(), "0".as_ref()]).spawn().unwrap();
    let mut line = String::new();
    std::io::BufReader::new(child.stdout.take().unwrap()).read_line(&mut line).unwrap();
    let addr = line.trim().rsplit("http://").next().unwrap().trim_end_matches('/').to_string();
    let mut s = std::net::TcpStream::connect(&addr).unwrap();
    write!(s, "GET /api/status HTTP/1.1\r\nHost: {addr}\r\nConnection: close\r\n\r\n").unwrap();
    let mut reply = String::new();
    s.read_to_string(&mut reply).unwrap();
    assert!(reply.starts_with("HTTP/1.1 200") && reply.contains("\"message\":\"step 4"), "{reply}");
    assert!(Command::new("kill").arg("-TERM").arg(child.id().to_string()).status().unwrap().success());
    let out = child.wait_with_output().unwrap();
    assert_eq!(out.status.code(), Some(0), "{}", String::from_utf8_lossy(&out.stderr));
    assert_eq!(test_support::file_map(&run), before, "the viewer changed the run folder");
}

//! The CDP driver's own tests, against pages served on loopback by a tiny HTTP server.

use std::collections::HashMap;
use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::time::{Duration, Instant};

use serde_json::json;

use crate::cdp::{Browser, MouseButton, MouseKind, chromium_or_skip};

/// Serves `routes` (path → (content type, body)) on 127.0.0.1 until the test binary exits;
/// anything else is a 404. Returns the base URL, "http://127.0.0.1:PORT".
fn serve(routes: &[(&str, &str, &str)]) -> String {
    let routes: HashMap<String, (String, String)> = routes
        .iter()
        .map(|(p, t, b)| (p.to_string(), (t.to_string(), b.to_string())))
        .collect();
    let listener = TcpListener::bind("127.0.0.1:0").expect("binding a loopback port");
    let base = format!("http://{}", listener.local_addr().unwrap());
    std::thread::spawn(move || {
        for stream in listener.incoming().flatten() {
            let routes = routes.clone();
            std::thread::spawn(move || respond(stream, &routes));
        }
    });
    base
}

fn respond(mut stream: TcpStream, routes: &HashMap<String, (String, String)>) {
    let _ = stream.set_read_timeout(Some(Duration::from_secs(10)));
    let mut request = Vec::new();
    let mut buf = [0u8; 4096];
    while !request.windows(4).any(|w| w == b"\r\n\r\n") {
        match stream.read(&mut buf) {
            Ok(0) | Err(_) => return,
            Ok(n) => request.extend_from_slice(&buf[..n]),
        }
    }
    let head = String::from_utf8_lossy(&request);
    let path = head.split_whitespace().nth(1).unwrap_or("/");
    let path = path.split('?').next().unwrap_or(path);
    let (status, ty, body) = match routes.get(path) {
        Some((ty, body)) => ("200 OK", ty.as_str(), body.as_str()),
        None => ("404 Not Found", "text/plain", "not found"),
    };
    let _ = write!(
        stream,
        "HTTP/1.1 {status}\r\nContent-Type: {ty}\r\nContent-Length: {}\r\nCache-Control: no-store\r\nConnection: close\r\n\r\n{body}",
        body.len()
    );
}

const HTML: &str = "text/html; charset=utf-8";

/// A page with no favicon request (a 404 favicon would be an error).
fn page(body: &str) -> String {
    format!(
        "<!doctype html><html><head><link rel=icon href=\"data:,\"></head><body>{body}</body></html>"
    )
}

async fn launch() -> Option<Browser> {
    chromium_or_skip()?;
    Some(Browser::launch().await.unwrap_or_else(|e| panic!("{e}")))
}

#[tokio::test]
async fn eval_returns_values_and_awaits_promises() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[("/", HTML, &page("<p id=p>hello</p>"))]);
    let page = browser.new_page(400, 300).await.unwrap();
    page.goto(&format!("{base}/")).await.unwrap();
    assert_eq!(page.eval("1+1").await.unwrap(), json!(2));
    assert_eq!(
        page.eval("document.getElementById('p').textContent")
            .await
            .unwrap(),
        json!("hello")
    );
    assert_eq!(
        page.eval("new Promise(r => setTimeout(() => r({a: [1, 'x']}), 50))")
            .await
            .unwrap(),
        json!({"a": [1, "x"]})
    );
    assert_eq!(page.eval("undefined").await.unwrap(), json!(null));
    assert_eq!(
        page.eval("[innerWidth, innerHeight, devicePixelRatio]")
            .await
            .unwrap(),
        json!([400, 300, 1])
    );
    let err = page
        .eval("function boom() { throw new Error('kaput') }\nboom()")
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("kaput") && err.contains("at boom"), "{err}");
    let err = page
        .eval("Promise.reject(new Error('refused'))")
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("refused"), "{err}");
    // A navigation that cannot happen is an error, not a hang.
    let closed = TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap();
    let err = page
        .goto(&format!("http://{closed}/"))
        .await
        .unwrap_err()
        .to_string();
    assert!(err.contains("ERR_CONNECTION_REFUSED"), "{err}");
    assert!(page.errors().is_empty(), "{:?}", page.errors());
}

#[tokio::test]
async fn console_errors_exceptions_and_failed_loads_are_reported() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[
        (
            "/clean",
            HTML,
            &page("<script>console.log('just saying', 42)</script>"),
        ),
        (
            "/bad",
            HTML,
            &page(
                "<script>console.error('bad thing', {n: 1})</script>\
                 <script src=\"/missing.js\"></script>\
                 <script>setTimeout(() => { throw new Error('uncaught one') }, 0)</script>",
            ),
        ),
    ]);
    let page = browser.new_page(400, 300).await.unwrap();
    page.goto(&format!("{base}/clean")).await.unwrap();
    assert!(page.errors().is_empty(), "{:?}", page.console());
    assert!(
        page.console()
            .iter()
            .any(|e| e.level == "log" && e.text == "just saying 42"),
        "{:?}",
        page.console()
    );

    let page = browser.new_page(400, 300).await.unwrap();
    page.goto(&format!("{base}/bad")).await.unwrap();
    page.wait_for(
        "new Promise(r => setTimeout(() => r(true), 100))",
        Duration::from_secs(30),
    )
    .await
    .unwrap();
    let errors = page.errors();
    assert!(errors.iter().any(|e| e.contains("bad thing")), "{errors:?}");
    assert!(
        errors
            .iter()
            .any(|e| e.contains("uncaught one") && e.contains("Uncaught")),
        "{errors:?}"
    );
    assert!(
        errors
            .iter()
            .any(|e| e.contains("404") && e.contains("/missing.js")),
        "{errors:?}"
    );
    assert_eq!(errors.len(), 3, "{errors:?}");
}

#[tokio::test]
async fn wait_for_sees_a_flag_and_times_out_helpfully() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[(
        "/",
        HTML,
        &page("<script>setTimeout(() => { window.ready = 'yes' }, 300)</script>"),
    )]);
    let page = browser.new_page(400, 300).await.unwrap();
    page.goto(&format!("{base}/")).await.unwrap();
    let start = Instant::now();
    assert_eq!(
        page.wait_for("window.ready", Duration::from_secs(10))
            .await
            .unwrap(),
        json!("yes")
    );
    assert!(
        start.elapsed() < Duration::from_secs(8),
        "{:?}",
        start.elapsed()
    );

    // The timeouts leave room for a slow answer: two chromiums share CI's 2 cores, and there a
    // trivial evaluation has taken more than 1.5 s to come back (the error then says "not
    // known", not the value this test wants to see named).
    let start = Instant::now();
    let err = page
        .wait_for(
            "window.never === 1 || window.ready.length - 3",
            Duration::from_secs(6),
        )
        .await
        .unwrap_err()
        .to_string();
    assert!(
        start.elapsed() < Duration::from_secs(15),
        "{:?}",
        start.elapsed()
    );
    assert!(
        err.contains("window.never === 1") && err.contains("it was 0") && err.contains("6s"),
        "{err}"
    );
    let err = page
        .wait_for("window.app.ready", Duration::from_secs(6))
        .await
        .unwrap_err()
        .to_string();
    assert!(
        err.contains("window.app.ready") && err.contains("TypeError"),
        "{err}"
    );
}

/// The viewer's WebGL2 needs, on SwiftShader: a LINEAR-filtered RGBA16F 3D texture (HALF_FLOAT),
/// a depth texture with comparison sampling (shadow maps), and an sRGB texture.
const WEBGL_PAGE: &str = r#"<canvas id=c width=4 height=4></canvas><script>
function run() {
  const gl = document.getElementById('c').getContext('webgl2');
  if (!gl) return { error: 'no webgl2 context' };
  const info = gl.getExtension('WEBGL_debug_renderer_info');
  const out = {
    version: gl.getParameter(gl.VERSION),
    renderer: info ? gl.getParameter(info.UNMASKED_RENDERER_WEBGL) : gl.getParameter(gl.RENDERER),
  };
  const compile = (type, src) => {
    const s = gl.createShader(type); gl.shaderSource(s, src); gl.compileShader(s);
    if (!gl.getShaderParameter(s, gl.COMPILE_STATUS)) throw new Error(gl.getShaderInfoLog(s));
    return s;
  };
  const program = (fs) => {
    const p = gl.createProgram();
    gl.attachShader(p, compile(gl.VERTEX_SHADER, `#version 300 es
      in vec2 pos; void main() { gl_Position = vec4(pos, 0.0, 1.0); }`));
    gl.attachShader(p, compile(gl.FRAGMENT_SHADER, `#version 300 es
      precision highp float; precision highp sampler3D; precision highp sampler2DShadow;
      out vec4 color; ${fs}`));
    gl.bindAttribLocation(p, 0, 'pos'); gl.linkProgram(p);
    if (!gl.getProgramParameter(p, gl.LINK_STATUS)) throw new Error(gl.getProgramInfoLog(p));
    return p;
  };
  const buf = gl.createBuffer();
  gl.bindBuffer(gl.ARRAY_BUFFER, buf);
  gl.bufferData(gl.ARRAY_BUFFER, new Float32Array([-1, -1, 3, -1, -1, 3]), gl.STATIC_DRAW);
  gl.enableVertexAttribArray(0); gl.vertexAttribPointer(0, 2, gl.FLOAT, false, 0, 0);
  // The RGBA8 target everything draws into.
  const target = gl.createTexture();
  gl.bindTexture(gl.TEXTURE_2D, target);
  gl.texStorage2D(gl.TEXTURE_2D, 1, gl.RGBA8, 4, 4);
  const fb = gl.createFramebuffer();
  const draw = (p, setup) => {
    gl.bindFramebuffer(gl.FRAMEBUFFER, fb);
    gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.COLOR_ATTACHMENT0, gl.TEXTURE_2D, target, 0);
    gl.viewport(0, 0, 4, 4); gl.useProgram(p); setup(p);
    gl.drawArrays(gl.TRIANGLES, 0, 3);
    const px = new Uint8Array(4); gl.readPixels(1, 1, 1, 1, gl.RGBA, gl.UNSIGNED_BYTE, px);
    return Array.from(px);
  };
  const clamp = (t) => {
    for (const p of [gl.TEXTURE_WRAP_S, gl.TEXTURE_WRAP_T, gl.TEXTURE_WRAP_R]) gl.texParameteri(t, p, gl.CLAMP_TO_EDGE);
  };

  // 1. RGBA16F 3D texture, 2x1x1, red 0 then 1 (half floats), LINEAR: u = 0.5 sits halfway.
  const vol = gl.createTexture();
  gl.activeTexture(gl.TEXTURE0); gl.bindTexture(gl.TEXTURE_3D, vol);
  gl.texImage3D(gl.TEXTURE_3D, 0, gl.RGBA16F, 2, 1, 1, 0, gl.RGBA, gl.HALF_FLOAT,
                new Uint16Array([0, 0, 0, 0x3c00, 0x3c00, 0, 0, 0x3c00]));
  gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_3D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  clamp(gl.TEXTURE_3D);
  const p3 = program(`uniform sampler3D vol; uniform float u;
    void main() { color = vec4(texture(vol, vec3(u, 0.5, 0.5)).r, 0.0, 0.0, 1.0); }`);
  out.volume = {};
  for (const u of [0.25, 0.5, 0.75]) {
    out.volume[u] = draw(p3, (p) => { gl.uniform1i(gl.getUniformLocation(p, 'vol'), 0); gl.uniform1f(gl.getUniformLocation(p, 'u'), u); })[0];
  }

  // 2. sRGB texture: sRGB 188 decodes to linear 0.503 when sampled.
  const srgb = gl.createTexture();
  gl.activeTexture(gl.TEXTURE1); gl.bindTexture(gl.TEXTURE_2D, srgb);
  gl.texImage2D(gl.TEXTURE_2D, 0, gl.SRGB8_ALPHA8, 1, 1, 0, gl.RGBA, gl.UNSIGNED_BYTE, new Uint8Array([188, 188, 188, 255]));
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  const ps = program(`uniform sampler2D t; void main() { color = vec4(texture(t, vec2(0.5)).rgb, 1.0); }`);
  out.srgb = draw(ps, (p) => gl.uniform1i(gl.getUniformLocation(p, 't'), 1))[0];

  // 3. Depth texture as a shadow map: render depth 0.25 into it, then compare-sample it.
  const depth = gl.createTexture();
  gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, depth);
  gl.texStorage2D(gl.TEXTURE_2D, 1, gl.DEPTH_COMPONENT24, 4, 4);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MIN_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_MAG_FILTER, gl.LINEAR);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_COMPARE_MODE, gl.COMPARE_REF_TO_TEXTURE);
  gl.texParameteri(gl.TEXTURE_2D, gl.TEXTURE_COMPARE_FUNC, gl.LEQUAL);
  clamp(gl.TEXTURE_2D);
  const shadowFb = gl.createFramebuffer();
  gl.bindFramebuffer(gl.FRAMEBUFFER, shadowFb);
  gl.framebufferTexture2D(gl.FRAMEBUFFER, gl.DEPTH_ATTACHMENT, gl.TEXTURE_2D, depth, 0);
  gl.drawBuffers([gl.NONE]); gl.readBuffer(gl.NONE);
  out.depthComplete = gl.checkFramebufferStatus(gl.FRAMEBUFFER) === gl.FRAMEBUFFER_COMPLETE;
  gl.viewport(0, 0, 4, 4); gl.clearDepth(0.25); gl.clear(gl.DEPTH_BUFFER_BIT);
  gl.bindTexture(gl.TEXTURE_2D, null);
  const pd = program(`uniform sampler2DShadow t; uniform float ref;
    void main() { color = vec4(texture(t, vec3(0.5, 0.5, ref)), 0.0, 0.0, 1.0); }`);
  gl.activeTexture(gl.TEXTURE2); gl.bindTexture(gl.TEXTURE_2D, depth);
  out.shadow = [0.2, 0.3].map((ref) => draw(pd, (p) => {
    gl.uniform1i(gl.getUniformLocation(p, 't'), 2); gl.uniform1f(gl.getUniformLocation(p, 'ref'), ref);
  })[0]);
  out.glError = gl.getError();
  return out;
}
let result; try { result = run(); } catch (e) { result = { error: String(e) }; }
window.result = result;
</script>"#;

#[tokio::test]
async fn webgl2_samples_half_float_3d_textures_depth_and_srgb() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[("/", HTML, &page(WEBGL_PAGE))]);
    let page = browser.new_page(64, 64).await.unwrap();
    page.goto(&format!("{base}/")).await.unwrap();
    let r = page
        .wait_for("window.result", Duration::from_secs(20))
        .await
        .unwrap();
    eprintln!("WebGL2 on this machine: {r}\nconsole: {:?}", page.console());
    assert!(r["error"].is_null(), "{r}");
    assert!(
        r["version"].as_str().unwrap().starts_with("WebGL 2.0"),
        "{r}"
    );
    let near = |v: &serde_json::Value, want: i64| (v.as_i64().unwrap() - want).abs() <= 3;
    assert!(
        near(&r["volume"]["0.5"], 128),
        "the midpoint of a LINEAR RGBA16F 3D texture: {r}"
    );
    assert!(
        near(&r["volume"]["0.25"], 0) && near(&r["volume"]["0.75"], 255),
        "the texel centres: {r}"
    );
    assert!(near(&r["srgb"], 128), "sRGB 188 sampled as linear: {r}");
    assert_eq!(r["depthComplete"], json!(true), "{r}");
    assert_eq!(
        r["shadow"],
        json!([255, 0]),
        "depth compare: 0.2 <= 0.25 lit, 0.3 shadowed: {r}"
    );
    assert_eq!(r["glError"], json!(0), "{r}");
    assert!(page.errors().is_empty(), "{:?}", page.errors());
}

#[tokio::test]
async fn screenshot_is_the_viewport() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[(
        "/",
        HTML,
        &page("<style>html,body{margin:0;height:100%;background:rgb(200,30,40)}</style>"),
    )]);
    let page = browser.new_page(320, 200).await.unwrap();
    page.goto(&format!("{base}/")).await.unwrap();
    let png = page.screenshot_png().await.unwrap();
    let img = image::load_from_memory_with_format(&png, image::ImageFormat::Png)
        .unwrap()
        .to_rgba8();
    assert_eq!(img.dimensions(), (320, 200));
    assert_eq!(img.get_pixel(160, 100).0, [200, 30, 40, 255]);
    assert_eq!(img.get_pixel(0, 0).0, [200, 30, 40, 255]);
    assert_eq!(img.get_pixel(319, 199).0, [200, 30, 40, 255]);
}

#[tokio::test]
async fn mouse_and_keys_reach_the_page() {
    let Some(browser) = launch().await else {
        return;
    };
    let base = serve(&[(
        "/",
        HTML,
        &page(
            "<style>html,body{margin:0;height:100%}</style><script>
             window.seen = [];
             for (const t of ['pointerdown', 'pointermove', 'pointerup'])
               addEventListener(t, e => seen.push([t, e.clientX, e.clientY, e.buttons]));
             addEventListener('wheel', e => seen.push(['wheel', e.deltaY]));
             addEventListener('keydown', e => seen.push(['keydown', e.key, e.code]));
             addEventListener('keyup', e => seen.push(['keyup', e.key]));
             </script>",
        ),
    )]);
    let page = browser.new_page(400, 300).await.unwrap();
    page.goto(&format!("{base}/")).await.unwrap();
    page.drag(MouseButton::Left, (10.0, 20.0), (50.0, 60.0), 2)
        .await
        .unwrap();
    page.mouse(MouseKind::Wheel { dx: 0.0, dy: 120.0 }, 100.0, 100.0)
        .await
        .unwrap();
    page.key("a").await.unwrap();
    page.key("Escape").await.unwrap();
    page.wait_for(
        "seen.some(e => e[0] === 'keyup' && e[1] === 'Escape') && seen.some(e => e[0] === 'wheel')",
        Duration::from_secs(30),
    )
    .await
    .unwrap();
    let seen = page.eval("seen").await.unwrap();
    let seen = seen.as_array().unwrap();
    let has = |e: serde_json::Value| seen.contains(&e);
    assert!(has(json!(["pointerdown", 10, 20, 1])), "{seen:?}");
    assert!(
        has(json!(["pointermove", 30, 40, 1])),
        "a drag holds the button: {seen:?}"
    );
    assert!(has(json!(["pointerup", 50, 60, 0])), "{seen:?}");
    assert!(has(json!(["wheel", 120])), "{seen:?}");
    assert!(
        has(json!(["keydown", "a", "KeyA"])) && has(json!(["keyup", "a"])),
        "{seen:?}"
    );
    assert!(has(json!(["keydown", "Escape", "Escape"])), "{seen:?}");
}

/// The live (not zombie) processes in process group `pgid`, or with `mark` in their command line
/// (chromium's crash handler leaves the group but names the profile), from /proc.
fn chromium_processes(pgid: u32, mark: &str) -> Vec<u32> {
    let mut members = Vec::new();
    for entry in std::fs::read_dir("/proc").unwrap().flatten() {
        let Ok(pid) = entry.file_name().to_string_lossy().parse::<u32>() else {
            continue;
        };
        let Ok(stat) = std::fs::read_to_string(entry.path().join("stat")) else {
            continue;
        };
        // "pid (comm) state ppid pgrp ...": comm may hold spaces, so split after its ')'.
        let Some(rest) = stat.rsplit_once(')').map(|(_, r)| r) else {
            continue;
        };
        let fields: Vec<&str> = rest.split_whitespace().collect();
        let cmdline = std::fs::read(entry.path().join("cmdline")).unwrap_or_default();
        let named = String::from_utf8_lossy(&cmdline).contains(mark);
        if fields.len() > 2 && fields[0] != "Z" && (fields[2] == pgid.to_string() || named) {
            members.push(pid);
        }
    }
    members
}

#[tokio::test]
async fn dropping_the_browser_kills_chromium() {
    let Some(browser) = launch().await else {
        return;
    };
    let pid = browser.pid();
    let profile = browser.profile_dir().to_owned();
    let page = browser.new_page(100, 100).await.unwrap();
    assert_eq!(page.eval("2*21").await.unwrap(), json!(42));
    drop(page);
    let mark = profile.to_str().unwrap().to_owned();
    let members = chromium_processes(pid, &mark);
    assert!(
        members.contains(&pid) && members.len() > 1,
        "chromium and its helpers: {members:?}"
    );
    assert!(profile.is_dir());
    // chromium's own temporary directory (its singleton socket, left behind by a kill) is in the
    // profile, not in /tmp where every run would add one.
    let own_tmp: Vec<_> = std::fs::read_dir(profile.join("tmp"))
        .unwrap()
        .flatten()
        .map(|e| e.file_name().to_string_lossy().into_owned())
        .collect();
    assert!(
        own_tmp.iter().any(|name| name.starts_with("org.chromium.")),
        "{own_tmp:?}"
    );
    drop(browser);
    assert!(
        !std::path::Path::new(&format!("/proc/{pid}")).exists(),
        "the browser process {pid} is gone (and reaped)"
    );
    assert!(
        !profile.exists(),
        "the profile {} is removed",
        profile.display()
    );
    // The renderers, the GPU process and the crash handler go too (init reaps them).
    let start = Instant::now();
    while !chromium_processes(pid, &mark).is_empty() && start.elapsed() < Duration::from_secs(20) {
        std::thread::sleep(Duration::from_millis(20));
    }
    assert_eq!(
        chromium_processes(pid, &mark),
        Vec::<u32>::new(),
        "chromium's processes are gone"
    );
}

#[tokio::test]
async fn a_failed_launch_shows_chromiums_stderr() {
    // /bin/sh as chromium: it rejects the first flag on stderr and exits. (Not a script written
    // here: exec'ing a file just written races other tests' forks, ETXTBSY.)
    let err = Browser::launch_with(std::path::Path::new("/bin/sh"), &[])
        .await
        .err()
        .expect("sh is no chromium")
        .to_string();
    assert!(
        err.contains("exited at launch") && err.to_lowercase().contains("option"),
        "{err}"
    );
}

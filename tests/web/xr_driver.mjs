// Drives livebake's page (web/livebake.js) in headless Chromium with an emulated headset:
// the Immersive Web Emulation Runtime (npm `iwer`, a Meta Quest 3 config, stereo) is
// installed before the page loads, the page enters an immersive-vr session and draws both
// eyes. Software GL (SwiftShader): no GPU needed.
//   node xr_driver.mjs CONFIG.json
// CONFIG: {"tools": node_modules' parent, "url", "out": directory, "fovy", "ipd", "lan_host",
//          "eye_size": [w, h], "frames": N, "steps": ["capture", "move_head", "wait_updates",
//          "wait_scene:G", "garbage", "frame_times", "static"]}
// Prints one JSON object: what each step saw. Eye pixels go to OUT/eye-I.rgba (rows bottom
// up, as readPixels returns them).
import fs from "fs";
import path from "path";

const config = JSON.parse(fs.readFileSync(process.argv[2], "utf8"));
const tools = path.join(config.tools, "node_modules");
const { chromium } = await import(path.join(tools, "playwright-core", "index.mjs"));
const iwer = fs.readFileSync(path.join(tools, "iwer", "build", "iwer.min.js"), "utf8");

const browser = await chromium.launch({
  executablePath: config.chromium || "/usr/bin/chromium",
  headless: true,
  // "lan_host": a name that resolves to 127.0.0.1, an origin Chromium does not trust as it
  // trusts localhost (plain http to a LAN address: no cross-origin isolation, no WebXR).
  args: ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader", "--ignore-gpu-blocklist"]
    .concat(config.lan_host ? [`--host-resolver-rules=MAP ${config.lan_host} 127.0.0.1`] : []),
});
const result = { steps: [], console: [] };
const timeout = (config.timeout_s || 120) * 1000;
try {
  const [w, h] = config.eye_size || [160, 120];
  const context = await browser.newContext({ viewport: { width: 2 * w, height: h }, deviceScaleFactor: 1 });
  await context.addInitScript({ content: iwer });
  await context.addInitScript({
    content: `window.__device = new IWER.XRDevice(IWER.metaQuest3, { stereoEnabled: true, fovy: ${config.fovy ?? Math.PI / 2}, ipd: ${config.ipd ?? 0.063} });
      window.__device.installRuntime({ forceInstall: true });`,
  });
  const page = await context.newPage();
  page.on("console", (m) => result.console.push(m.text()));
  page.on("pageerror", (e) => result.console.push(`pageerror: ${e.message}`));
  await page.goto(config.url);
  await page.waitForFunction(() => window.livebake && window.livebake.vao && window.livebake.updates > 0, null, { timeout });
  if (!config.no_vr) {
    await page.evaluate(() => window.livebake.enterVR().then(() => true));
    await page.waitForFunction((n) => window.livebake.xrFrames >= n, config.frames || 3, { timeout });
  }
  const status = () => page.evaluate(() => {
    const s = window.livebake;
    return { updates: s.updates, pages: s.pagesWritten, bytes_uploaded: s.bytesUploaded, upload_calls: s.uploadCalls, fenced: s.fenced, shared_ring: s.sharedRing ?? null, full: s.fullSeen, generation: s.generation,
      scenes: s.scenesReceived, xr_frames: s.xrFrames, frames: s.frames, pose: s.lastPoseSent || null,
      frame_ms: s.lastFrameMean ?? null, layer_pages: s.lightmap ? s.lightmap.layerPages : null, connected: s.connected, errors: s.errors, now: performance.now() };
  });
  for (const step of config.steps || []) {
    if (step === "capture") {
      const eyes = await page.evaluate(async () => {
        const eyes = await window.livebake.captureEyes();
        return eyes.map((e) => {
          let bin = "";
          for (let i = 0; i < e.pixels.length; i += 0x8000) bin += String.fromCharCode(...e.pixels.subarray(i, i + 0x8000));
          return { ...e, pixels: btoa(bin) };
        });
      });
      eyes.forEach((e, i) => {
        const file = path.join(config.out, `eye-${i}.rgba`);
        fs.writeFileSync(file, Buffer.from(e.pixels, "base64"));
        e.file = file;
        delete e.pixels;
      });
      result.steps.push({ step, eyes });
    } else if (step === "move_head") {
      // One metre along +x in the headset's own tracking space; the page's next pose
      // message carries it to the runtime's camera.
      const before = await status();
      await page.evaluate(() => { const p = window.__device.position; window.__device.position.set(p.x + 1, p.y, p.z); });
      await page.waitForTimeout(600);
      const after = await status();
      const server = await page.evaluate(() => fetch("/status.json").then((r) => r.json()));
      result.steps.push({ step, before: before.pose, after: after.pose, server_pose: server.last_pose });
    } else if (step === "wait_updates") {
      const before = await status();
      await page.waitForFunction((n) => window.livebake.updates > n, before.updates + 1, { timeout });
      result.steps.push({ step, before, after: await status() });
    } else if (step.startsWith("wait_scene:")) {
      const g = Number(step.split(":")[1]);
      // Generation g's scene and its whole map (each scene the page gets comes with one).
      await page.waitForFunction((g) => window.livebake.generation >= g && window.livebake.fullSeen >= g, g, { timeout });
      result.steps.push({ step, after: await status() });
    } else if (step === "frame_times") {
      await page.waitForFunction(() => window.livebake.lastFrameMean != null, null, { timeout });
      result.steps.push({ step, after: await status() });
    } else if (step === "snap_turn" || step === "teleport") {
      // The right controller: thumbstick right for a moment (snap turn), or pointed 45°
      // down and its trigger pressed and released (teleport: select).
      // Waits for the headset to draw n more frames (time alone does not: a headless page
      // may draw nothing while the test waits).
      const frames = async (n) => {
        const now = await page.evaluate(() => window.livebake.xrFrames);
        await page.waitForFunction((k) => window.livebake.xrFrames >= k, now + n, { timeout });
      };
      const views = () => page.evaluate(() => window.livebake.lastViews.map((v) => ({ position: v.position, forward: v.forward })));
      // The controllers connect a few frames into the session.
      await page.waitForFunction(() => window.livebake.xr.session.inputSources.length >= 2, null, { timeout });
      await frames(4);
      const before = await views();
      if (step === "snap_turn") {
        await page.evaluate(() => window.__device.controllers.right.updateAxes("thumbstick", 1, 0));
        await frames(8);
        await page.evaluate(() => window.__device.controllers.right.updateAxes("thumbstick", 0, 0));
      } else {
        await page.evaluate(() => {
          const s = Math.sin(-Math.PI / 8), c = Math.cos(-Math.PI / 8);
          window.__device.controllers.right.quaternion.set(s, 0, 0, c);
        });
        await frames(4);
        await page.evaluate(() => window.__device.controllers.right.updateButtonValue("trigger", 1));
        await frames(4);
        await page.evaluate(() => window.__device.controllers.right.updateButtonValue("trigger", 0));
      }
      await frames(8);
      const after = await views();
      const counts = await page.evaluate(() => ({
        snap_turns: window.livebake.snapTurns || 0, teleports: window.livebake.teleports || 0, xr_frames: window.livebake.xrFrames,
        axes: Array.from(window.livebake.xr.session.inputSources).map((x) => x.gamepad && Array.from(x.gamepad.axes)),
      }));
      result.steps.push({ step, before, after, ...counts });
    } else if (step === "edit") {
      // A save of the scene (hot reload).
      fs.writeFileSync(config.edit.path, config.edit.content);
    } else if (step === "garbage_clients") {
      // A second client that sends garbage (the server must close it) and a third that
      // goes away mid-handshake; the page's own connection must not notice.
      const closed = await page.evaluate(() => new Promise((resolve) => {
        const url = `ws://${location.host}/socket${location.search}`;
        const gone = new WebSocket(url);
        gone.close();
        const bad = new WebSocket(url);
        bad.binaryType = "arraybuffer";
        bad.onopen = () => bad.send(new Uint8Array([42, 1, 2, 3]));
        bad.onclose = () => resolve(true);
        setTimeout(() => resolve(false), 20000);
      }));
      result.steps.push({ step, garbage_closed: closed, after: await status() });
    } else if (step.startsWith("sleep:")) {
      // Polled on animation frames: a headless page left alone may stop drawing (the
      // emulator's frames stall), which would be measured as slow frames.
      const until = (await page.evaluate(() => performance.now())) + Number(step.split(":")[1]);
      await page.waitForFunction((t) => performance.now() >= t, until, { timeout: timeout + Number(step.split(":")[1]), polling: "raf" });
    } else if (step === "status") {
      result.steps.push({ step, after: await status() });
    } else if (step === "screenshot") {
      const file = path.join(config.out, "page.png");
      await page.screenshot({ path: file });
      result.steps.push({ step, file });
    } else if (step === "mean_pixel") {
      // The desktop canvas's mean colour and the fraction of pixels brighter than the
      // background (static export check).
      const mean = await page.evaluate(() => {
        const c = document.getElementById("view");
        const gl = c.getContext("webgl2");
        const px = new Uint8Array(c.width * c.height * 4);
        gl.readPixels(0, 0, c.width, c.height, gl.RGBA, gl.UNSIGNED_BYTE, px);
        let s = [0, 0, 0], lit = 0;
        for (let i = 0; i < px.length; i += 4) {
          s[0] += px[i]; s[1] += px[i + 1]; s[2] += px[i + 2];
          if (px[i] + px[i + 1] + px[i + 2] > 200) lit++;
        }
        return { mean: s.map((v) => v / (px.length / 4)), lit: lit / (px.length / 4) };
      });
      result.steps.push({ step, ...mean });
    } else throw new Error(`unknown step ${step}`);
  }
  result.final = await status();
} catch (e) {
  result.error = String(e && e.stack || e);
} finally {
  await browser.close();
}
process.stdout.write(JSON.stringify(result));

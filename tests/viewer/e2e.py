"""Drives the viewer page in headless Chromium (selenium + Debian's chromium-driver).

    e2e.py trained URL OUTDIR            a trained run: drawn, changes with a drag and a mode,
                                         snap and compare, keyframes exported
    e2e.py live URL OUTDIR RUN PID [SCREENSHOT]
                                         a run being trained (by process PID): the page waits,
                                         then the training curve appears and newer checkpoints
                                         are drawn

Checks are made on screenshots of the page's elements (Pillow); each failure exits non-zero
with one line saying what was not seen. Screenshots are kept in OUTDIR.
"""
import io
import os
import sys
import time

from PIL import Image, ImageChops, ImageStat
from selenium import webdriver
from selenium.webdriver.chrome.service import Service
from selenium.webdriver.common.action_chains import ActionChains
from selenium.webdriver.common.by import By
from selenium.webdriver.support.ui import Select


def fail(msg):
    print("viewer e2e: FAILED: " + msg, file=sys.stderr)
    sys.exit(1)


def browser():
    o = webdriver.ChromeOptions()
    o.binary_location = "/usr/bin/chromium"
    for a in ["--headless=new", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage", "--window-size=1280,1000"]:
        o.add_argument(a)
    return webdriver.Chrome(service=Service("/usr/bin/chromedriver"), options=o)


def wait(what, cond, timeout=90):
    t0 = time.time()
    while time.time() - t0 < timeout:
        v = cond()
        if v:
            return v
        time.sleep(0.2)
    fail(f"{what} (waited {timeout} s)")


def data(d, key):
    return d.execute_script(f"return document.body.dataset.{key} || ''")


def frames(d):
    return int(data(d, "frames") or 0)


def full_frame_after(d, n, what):
    wait(what, lambda: frames(d) > n and data(d, "full") == "true")


def shot(el, path):
    png = el.screenshot_as_png
    with open(path, "wb") as f:
        f.write(png)
    return Image.open(io.BytesIO(png)).convert("RGB")


def drawn(img):
    """The scene is drawn: many distinct colours and real contrast, not a flat background."""
    small = img.resize((64, 64))
    colours = len(set(small.getdata()))
    spread = max(ImageStat.Stat(img).stddev)
    return colours > 40 and spread > 8, f"{colours} colours, stddev {spread:.1f}"


def difference(a, b):
    return sum(ImageStat.Stat(ImageChops.difference(a, b)).mean) / 3


def drag(d, el, dx, dy):
    a = ActionChains(d).move_to_element(el).click_and_hold()
    for _ in range(6):
        a = a.move_by_offset(dx // 6, dy // 6).pause(0.05)
    a.release().perform()


def snap(d, index):
    Select(d.find_element(By.ID, "views")).select_by_index(index)
    d.find_element(By.ID, "snap").click()
    wait("the comparison's error heat map", lambda: "PSNR" in d.find_element(By.ID, "cmp-err-cap").text)


def trained(d, url, out):
    d.get(url)
    Select(d.find_element(By.ID, "res")).select_by_value("128")
    canvas = d.find_element(By.ID, "view")
    full_frame_after(d, 0, "a first full-resolution frame")
    a = shot(canvas, f"{out}/e2e-1-start.png")
    ok, why = drawn(a)
    if not ok:
        fail(f"the first frame shows no scene ({why})")
    n = frames(d)
    drag(d, canvas, 180, 40)
    full_frame_after(d, n, "a new full frame after dragging")
    b = shot(canvas, f"{out}/e2e-2-dragged.png")
    if difference(a, b) < 4:
        fail(f"the frame did not change with the drag (mean difference {difference(a, b):.2f})")
    n = frames(d)
    Select(d.find_element(By.ID, "mode")).select_by_value("depth")
    full_frame_after(d, n, "a depth frame")
    c = shot(canvas, f"{out}/e2e-3-depth.png")
    if difference(b, c) < 4:
        fail("the depth mode looks like the colour mode")
    Select(d.find_element(By.ID, "mode")).select_by_value("rgb")
    snap(d, 25)
    for img in ["cmp-nerf", "cmp-gt", "cmp-err"]:
        wait(f"the {img} picture", lambda: d.execute_script(f"return document.getElementById('{img}').naturalWidth") == 64)
    shot(d.find_element(By.ID, "compare"), f"{out}/e2e-4-compare.png")
    d.find_element(By.ID, "addkey").click()
    drag(d, canvas, -150, 0)
    d.find_element(By.ID, "addkey").click()
    d.find_element(By.ID, "export").click()
    wait("the exported path", lambda: "frames" in d.find_element(By.ID, "exportmsg").text)
    print("viewer e2e: trained run drawn, changes with a drag and the depth mode, compared, path exported:", d.find_element(By.ID, "exportmsg").text)


def live(d, url, out, run, trainer, screenshot):
    d.get(url)
    Select(d.find_element(By.ID, "res")).select_by_value("128")
    status = wait("a status line", lambda: d.find_element(By.ID, "status").text)
    print("viewer e2e: live run, first status:", status)
    curves = d.find_element(By.ID, "curves")

    def curve_pixels():
        img = shot(curves, f"{out}/e2e-5-curves.png")
        return sum(1 for p in img.getdata() if abs(p[0] - 102) < 30 and abs(p[1] - 204) < 30 and p[2] > 220) > 30

    wait("the training loss curve", curve_pixels, timeout=120)
    wait("a frame from a checkpoint written during training", lambda: frames(d) > 0, timeout=120)
    first = int(data(d, "step"))
    if screenshot:
        snap(d, 25)
        time.sleep(3)
        img = Image.open(io.BytesIO(d.get_screenshot_as_png())).convert("RGB")
        img = img.resize((img.width * 3 // 5, img.height * 3 // 5), Image.LANCZOS).quantize(96)
        img.save(screenshot, optimize=True)
        print("viewer e2e: screenshot", screenshot)
    # A newer checkpoint is drawn: while the trainer runs, one written after the first frame's;
    # once it has ended (a loaded machine starves the low-priority viewer), its last one.
    def newer():
        step = int(data(d, "step") or 0)
        return step > first or (not alive(trainer) and step == last_checkpoint(run))

    wait(f"a newer checkpoint than step {first} (or the run's last)", newer, timeout=120)
    print(f"viewer e2e: live run: curve drawn, checkpoints followed from step {first} to {data(d, 'step')}")


def alive(pid):
    try:
        os.kill(pid, 0)
        return True
    except OSError:
        return False


def last_checkpoint(run):
    steps = [int(f[5:13]) for f in os.listdir(os.path.join(run, "checkpoints")) if f.startswith("step-") and f.endswith(".ckpt")]
    return max(steps, default=-1)


def main():
    kind, url, out = sys.argv[1:4]
    d = browser()
    try:
        if kind == "trained":
            trained(d, url, out)
        else:
            live(d, url, out, sys.argv[4], int(sys.argv[5]), sys.argv[6] if len(sys.argv) > 6 else "")
    finally:
        d.quit()


main()

"""Headless-Chromium checks of pages the package writes (the viewer, the demo report)."""

import shutil

import pytest


def browser_check(page_path, shots_dir):
    """Open the page in headless Chromium; return what a user would see: console errors,
    whether pressing play, dragging and switching clips each changed the picture, and the
    frame label after playing, whether the picture holds still once paused, and the label
    after scrubbing to frame index 10 (of the last clip). Only the page's first viewer is
    driven. Skips when Playwright or Chromium is missing."""
    playwright = pytest.importorskip("playwright.sync_api", reason="playwright not installed")
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    if chromium is None:
        pytest.skip("chromium not installed: the viewer is not checked in a browser")
    seen = {"errors": []}
    with playwright.sync_playwright() as p:
        browser = p.chromium.launch(executable_path=chromium, args=[
            "--no-sandbox", "--disable-gpu", "--disable-background-networking",
            "--disable-component-update", "--disable-sync", "--no-first-run"])
        try:
            page = browser.new_page(viewport={"width": 1000, "height": 900})
            page.on("console", lambda m: seen["errors"].append(m.text)
                    if m.type == "error" else None)
            page.on("pageerror", lambda e: seen["errors"].append(str(e)))
            page.goto(page_path.as_uri())
            canvas = page.locator(".bm-viewer canvas").first
            canvas.scroll_into_view_if_needed()
            first = canvas.screenshot(path=shots_dir / "first.png")
            seen["label_before"] = page.locator(".bm-frame").first.text_content()
            page.locator(".bm-play").first.click()
            page.wait_for_timeout(800)
            played = canvas.screenshot(path=shots_dir / "played.png")
            seen["label_after"] = page.locator(".bm-frame").first.text_content()
            page.locator(".bm-play").first.click()  # pause: the picture holds still
            still = canvas.screenshot()
            page.wait_for_timeout(300)
            seen["paused_still"] = canvas.screenshot() == still
            box = canvas.bounding_box()
            x, y = box["x"] + box["width"] / 2, box["y"] + box["height"] / 2
            page.mouse.move(x, y)
            page.mouse.down()
            page.mouse.move(x + 150, y - 40, steps=5)
            page.mouse.up()
            turned = canvas.screenshot(path=shots_dir / "turned.png")
            n = page.locator(".bm-clip").first.locator("option").count()
            page.locator(".bm-clip").first.select_option(index=n - 1)
            switched = canvas.screenshot(path=shots_dir / "switched.png")
            page.locator(".bm-time").first.fill("10")
            seen["label_scrubbed"] = page.locator(".bm-frame").first.text_content()
        finally:
            browser.close()
    seen.update(played=played != first, turned=turned != still, switched=switched != turned,
                options=n)
    return seen

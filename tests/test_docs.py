"""The manual (docs/, ``make docs``): it builds with warnings as errors, a real browser
(headless Chromium) draws its pages with every image and internal link in place, and its
reference pages list every command, parameter, topic and message of the code.

The site is built once per session, incrementally into ``docs/_build/html`` (the directory of
``make docs``; after ``make docs`` only the generated pages are read again). The reference is
compared with the code through the code's own objects (the argument parser, the schemas, the
parameters an rclpy node really declares, the topic tables), not through the manual's generator.
"""

from __future__ import annotations

import functools
import html
import http.server
import json
import os
import re
import shutil
import subprocess
import sys
import threading
from collections.abc import Iterator
from pathlib import Path
from urllib.parse import unquote, urldefrag, urlparse

import pytest

ROOT = Path(__file__).resolve().parents[1]
DOCS = ROOT / "docs"
SITE = DOCS / "_build" / "html"
PAPERS = ROOT.parent / "shared" / "papers"
#: The three pages the issue names: the start page, one tutorial, the parameter reference.
PAGES = ("index.html", "tutorials/polishing.html", "reference/parameters.html")

bs4 = pytest.importorskip("bs4", reason="the docs extra (make docs) installs beautifulsoup4")


# -- the built site --------------------------------------------------------------------------------
@pytest.fixture(scope="session")
def site() -> Path:
    """docs/_build/html, built now with the command of ``make docs`` (warnings are errors)."""
    sphinx = Path(sys.executable).with_name("sphinx-build")
    if not sphinx.exists():
        pytest.fail("sphinx-build is not installed in this environment: run `make docs` first")
    cmd = [str(sphinx), "-W", "--keep-going", "-q", "-b", "html", str(DOCS), str(SITE)]
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=900, cwd=ROOT)
    assert done.returncode == 0, f"the manual does not build:\n{done.stdout}\n{done.stderr}"
    return SITE


@functools.cache
def _soup(path: Path) -> bs4.BeautifulSoup:
    return bs4.BeautifulSoup(path.read_text(encoding="utf-8"), "html.parser")


def _pages(site: Path) -> list[Path]:
    return sorted(p for p in site.rglob("*.html") if "_static" not in p.parts)


def _local_target(page: Path, url: str, site: Path) -> tuple[Path, str] | None:
    """(file, fragment) of a link of ``page`` into the site; None for an external link."""
    parsed = urlparse(url)
    if parsed.scheme or parsed.netloc or url.startswith(("mailto:", "data:", "javascript:")):
        return None
    path, fragment = parsed.path, parsed.fragment
    target = page if not path else (page.parent / unquote(path)).resolve()
    return target, fragment


_ATTRIBUTE = re.compile(r"<(a|img|link|script)\b[^>]*?\s(href|src)=\"([^\"]*)\"", re.S)
_ID = re.compile(r"\sid=\"([^\"]+)\"")


@functools.cache
def _ids(path: Path) -> frozenset[str]:
    return frozenset(_ID.findall(path.read_text(encoding="utf-8")))


def test_every_internal_link_and_image_of_the_site_resolves(site: Path) -> None:
    """Every <a href> into the site names an existing file and, with a #fragment, an element of
    that id; every <img src>, stylesheet and script is a file (a static check of every page;
    Sphinx writes its attributes quoted, so a regular expression reads them)."""
    broken = []
    for page in _pages(site):
        for tag, _attr, url in _ATTRIBUTE.findall(page.read_text(encoding="utf-8")):
            found = _local_target(page, html.unescape(url), site)
            if found is None:
                continue
            target, fragment = found
            if target.is_dir():
                target = target / "index.html"
            if not target.is_file():
                broken.append(f"{page.relative_to(site)}: {tag} {url} (no file)")
            elif fragment and target.suffix == ".html" and fragment not in _ids(target):
                broken.append(f"{page.relative_to(site)}: {url} (no id {fragment!r})")
    assert not broken, "\n".join(broken[:40])
    assert len(_pages(site)) > 40  # the API pages are there too


# -- the browser -----------------------------------------------------------------------------------
def _find_chromium() -> str | None:
    for name in ("chromium", "chromium-browser"):
        path = shutil.which(name)
        if path:
            return path
    return None


@pytest.fixture(scope="session")
def chromium() -> str:
    """Debian's chromium; installed with apt-get when missing and this is root (as on CI, where
    .ci/run installs it first). Skipped only when it cannot be installed."""
    found = _find_chromium()
    if found:
        return found
    if os.geteuid() != 0 or shutil.which("apt-get") is None:
        pytest.skip("chromium is not installed and cannot be (not root, or no apt-get)")
    for args in (["apt-get", "update"], ["apt-get", "install", "-y", "chromium"]):
        done = subprocess.run(args, capture_output=True, text=True, timeout=900)
        if done.returncode != 0:
            reason = (done.stderr or done.stdout).strip().splitlines()[-1:]
            pytest.skip(f"chromium cannot be installed: {' '.join(args)}: {reason}")
    found = _find_chromium()
    if found is None:
        pytest.skip("chromium cannot be installed: apt-get installed no chromium binary")
    return found


#: Served at /__check__.html?page=PAGE: loads PAGE in a frame (same origin) and, once the
#: frame and its images have loaded, writes what the browser drew into #result as JSON.
HARNESS = """<!doctype html><html><body>
<pre id="result">pending</pre>
<iframe id="frame" style="width:1280px;height:900px"></iframe>
<script>
const page = new URLSearchParams(location.search).get("page");
const frame = document.getElementById("frame");
frame.onload = () => {
  const doc = frame.contentDocument;
  const images = Array.from(doc.images).map(i => ({
    src: i.currentSrc || i.src, complete: i.complete, width: i.naturalWidth}));
  const links = Array.from(doc.querySelectorAll("a[href]")).map(a => a.href)
    .filter(h => h.startsWith(location.origin));
  const main = doc.querySelector("article") || doc.body;
  const box = main.getBoundingClientRect();
  document.getElementById("result").textContent = JSON.stringify({
    title: doc.title, h1: (doc.querySelector("h1") || {}).textContent || "",
    text: main.innerText.length, width: box.width, height: box.height,
    tables: doc.querySelectorAll("article table").length, images, links});
};
frame.src = "/" + page;
</script></body></html>"""


class _Handler(http.server.SimpleHTTPRequestHandler):
    def do_GET(self) -> None:  # noqa: N802 (http.server's name)
        if self.path.startswith("/__check__.html"):
            body = HARNESS.encode()
            self.send_response(200)
            self.send_header("Content-Type", "text/html; charset=utf-8")
            self.send_header("Content-Length", str(len(body)))
            self.end_headers()
            self.wfile.write(body)
            return
        super().do_GET()

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture(scope="session")
def server(site: Path) -> Iterator[str]:
    """The built site over HTTP on 127.0.0.1 (a free port)."""
    handler = functools.partial(_Handler, directory=str(site))
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), handler)
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    try:
        yield f"http://127.0.0.1:{httpd.server_address[1]}"
    finally:
        httpd.shutdown()
        httpd.server_close()


def _chromium_args(chromium: str, tmp: Path) -> list[str]:
    return [
        chromium, "--headless", "--no-sandbox", "--disable-gpu", "--hide-scrollbars",
        "--no-first-run", "--disable-extensions", f"--user-data-dir={tmp / 'profile'}",
        "--window-size=1280,900",
    ]  # fmt: skip


def _drawn(chromium: str, server: str, page: str, tmp: Path) -> dict:
    cmd = [
        *_chromium_args(chromium, tmp), "--virtual-time-budget=15000", "--dump-dom",
        f"{server}/__check__.html?page={page}",
    ]  # fmt: skip
    done = subprocess.run(cmd, capture_output=True, text=True, timeout=120)
    match = re.search(r'<pre id="result">(.*?)</pre>', done.stdout, re.S)
    assert match and match.group(1) != "pending", f"{page}: no result\n{done.stderr[-2000:]}"
    return json.loads(bs4.BeautifulSoup(match.group(1), "html.parser").text)


@pytest.mark.parametrize("page", PAGES)
def test_chromium_draws_the_page_with_its_images_and_links(
    chromium: str, server: str, site: Path, page: str, tmp_path: Path
) -> None:
    drawn = _drawn(chromium, server, page, tmp_path)
    assert drawn["h1"].strip(), f"{page}: no title drawn"
    assert drawn["text"] > 500 and drawn["width"] > 500 and drawn["height"] > 500, drawn
    missing = [i["src"] for i in drawn["images"] if not i["complete"] or i["width"] == 0]
    assert not missing, f"{page}: images the browser could not draw: {missing}"
    broken = []
    for url in drawn["links"]:
        target, fragment = urldefrag(urlparse(url).path + ("#" + urldefrag(url)[1]))
        file = site / unquote(target.lstrip("/"))
        if file.is_dir():
            file = file / "index.html"
        if not file.is_file():
            broken.append(url)
        elif fragment and file.suffix == ".html" and _soup(file).find(id=fragment) is None:
            broken.append(url)
    assert not broken, f"{page}: links to nothing: {broken}"
    if page == "index.html":
        assert drawn["images"], "the start page shows its figure"
    if page == "reference/parameters.html":
        assert drawn["tables"] >= 20, drawn["tables"]


def test_chromium_screenshots_are_not_blank(chromium: str, site: Path, tmp_path: Path) -> None:
    """The three pages as a 1280x900 screenshot: a picture with text, not a blank window."""
    from matplotlib.image import imread

    for page in PAGES:
        out = tmp_path / (Path(page).stem + ".png")
        cmd = [*_chromium_args(chromium, tmp_path), f"--screenshot={out}", (site / page).as_uri()]
        subprocess.run(cmd, capture_output=True, timeout=120, check=False)
        assert out.is_file(), f"{page}: no screenshot"
        pixels = imread(out)
        assert pixels.shape[:2] == (900, 1280), pixels.shape
        assert float(pixels[..., :3].std()) > 0.05, f"{page}: the screenshot is blank"


# -- the reference matches the code ----------------------------------------------------------------
def _codes(element: bs4.element.Tag) -> set[str]:
    return {c.get_text() for c in element.find_all("code")}


def _section(site: Path, page: str, section_id: str) -> bs4.element.Tag:
    found = _soup(site / page).find(id=section_id)
    assert found is not None, f"{page}: no section {section_id!r}"
    return found


def _commands(parser, words: tuple[str, ...]):  # noqa: ANN001, ANN202
    import argparse

    yield words, parser
    for action in parser._actions:
        if isinstance(action, argparse._SubParsersAction):
            for name, sub in action.choices.items():
                yield from _commands(sub, (*words, name))


def test_every_command_and_option_is_in_the_reference(site: Path) -> None:
    """Each command of ``ffmpc`` (the studies' entry-point commands included) has its section,
    and every option string of its parser is in it."""
    from ffmpc_ros.cli import build_parser

    seen = 0
    for words, parser in _commands(build_parser(), ("ffmpc",)):
        section = _section(site, "reference/cli.html", "cli-" + "-".join(words).replace("_", "-"))
        shown = _codes(section)
        for action in parser._actions:
            for flag in action.option_strings:
                if flag not in ("-h", "--help"):
                    assert flag in shown, f"{' '.join(words)} {flag} is not in the reference"
                    seen += 1
    assert seen > 100  # the parser really has its options
    for name in ("study", "tune", "demo"):  # entry-point commands (studies/cli.py)
        _section(site, "reference/cli.html", f"cli-ffmpc-{name}")


def test_every_scenario_and_study_parameter_is_in_the_reference(site: Path) -> None:
    from ffmpc_core.impact.scenario import EXPLORATION_SCHEMA, IMPACT_SCHEMA
    from ffmpc_core.scenario import SCHEMA

    for section_id, names in (
        ("params-scenario", list(SCHEMA)),
        ("params-impact", list(IMPACT_SCHEMA.params)),
        ("params-explore", list(EXPLORATION_SCHEMA.params)),
    ):
        shown = _codes(_section(site, "reference/parameters.html", section_id))
        missing = [n for n in names if n not in shown]
        assert not missing, f"{section_id}: not in the reference: {missing}"


def test_every_parameter_a_node_declares_is_in_the_reference(site: Path) -> None:
    """Declare each node's parameters on a real rclpy node (what ``ros2 param list`` shows) and
    find each name in that node's section."""
    import rclpy
    from rclpy.node import Node

    from ffmpc_ros.params import NODE_SPECS, declare_node_parameters

    context = rclpy.Context()
    rclpy.init(context=context)
    try:
        for name, spec in NODE_SPECS.items():
            node = Node(f"docs_{name}", context=context)
            try:
                declared = declare_node_parameters(node, spec)
            finally:
                node.destroy_node()
            shown = _codes(
                _section(site, "reference/parameters.html", "node-" + name.replace("_", "-"))
            )
            missing = [p for p in declared if p not in shown]
            assert not missing, f"node {name}: not in the reference: {missing}"
    finally:
        rclpy.shutdown(context=context)


def test_every_topic_layout_and_service_is_in_the_reference(site: Path) -> None:
    from ffmpc_ros import layouts, topics

    shown = _codes(_soup(site / "reference/topics.html"))
    rows = (*topics.TOPICS, *topics.IMPACT_GRAPH_TOPICS, *topics.VIEW_TOPICS,
            *topics.REFERENCE_TOPICS)  # fmt: skip
    for name, ros_type, _publisher in rows:
        assert name in shown and ros_type in shown, name
    for service in (topics.TARE_SERVICE, topics.IMPACT_RESET_SERVICE,
                    topics.CONTACT_LEARNER_RESET_SERVICE):  # fmt: skip
        assert service in shown, service
    for layout in layouts.LAYOUTS.values():
        section = _section(site, "reference/topics.html", "layout-" + layout.name.replace("_", "-"))
        assert layout.label in _codes(section)
        assert {f.name for f in layout.fields} <= _codes(section), layout.name


def test_every_message_definition_is_in_the_reference(site: Path) -> None:
    from ffmpc_msgs.msg import MpcCommand

    for path in sorted((ROOT / "msg").glob("*.msg")):
        section = _section(
            site, "reference/messages.html", f"msg-ffmpc-msgs-msg-{path.stem.lower()}"
        )
        assert path.read_text(encoding="utf-8").strip().splitlines()[-1] in section.get_text()
    section = _section(site, "reference/messages.html", "msg-ffmpc-msgs-msg-mpccommand")
    assert set(MpcCommand.get_fields_and_field_types()) <= _codes(section)


def test_every_equation_of_both_papers_is_in_the_map(site: Path) -> None:
    """Every numbered equation of the two papers has its row in the generated map (the build
    itself fails for one that no docstring names and no note explains)."""
    if not PAPERS.is_dir():
        pytest.skip(f"the papers are not beside this checkout ({PAPERS})")
    page = _soup(site / "explanation/equations.html")
    for paper_file, section_id in (
        ("force-feedback-mpc-soft-contact.md", "eq-kleff2024"),
        ("safe-impacts-soft-contacts-learned-deformations.md", "eq-dehio2020"),
    ):
        text = (PAPERS / paper_file).read_text(encoding="utf-8")
        numbers = {int(n) for n in re.findall(r"\\quad \((\d+)\)\$\$", text)}
        numbers |= {int(n) for n in re.findall(r"\((\d+)\)\$\$", text)}
        numbers |= {int(n) for n in re.findall(r"\((\d+)b\)\$\$", text)}
        assert len(numbers) > 10, paper_file
        section = page.find(id=section_id)
        assert section is not None
        rows = {td.get_text().strip() for td in section.select("tbody tr td:first-child")}
        missing = sorted(n for n in numbers if f"eq {n}" not in rows)
        assert not missing, f"{paper_file}: equations without a row: {missing}"


#: Words of a lab notebook that a user-facing page must not carry.
HISTORY = re.compile(
    r"previous session|this session|earlier session|before this change|this branch|"
    r"\bat commit\b|\bthe base commit\b",
    re.I,
)
#: A hex word with a letter and a digit, not part of a number (``1.9768855627488868e-07``).
HASH = re.compile(r"(?<![\w.-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w-])")


def test_no_page_carries_history_or_commit_hashes(site: Path) -> None:
    found = []
    for page in _pages(site):
        text = _soup(page).get_text(" ")
        for pattern in (HISTORY, HASH):
            for match in pattern.finditer(text):
                found.append(f"{page.relative_to(site)}: {match.group(0)!r}")
    assert not found, "\n".join(found[:40])

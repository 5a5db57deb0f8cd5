"""The Snakemake workflow: lint-clean, plans the targets, and fails clearly without data; the
smoke study builds everything, and its executed notebooks show what they save."""

from __future__ import annotations

import base64
import hashlib
import html
import json
import re
import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest
import yaml
from conftest import workdir as _workdir  # shared with the smoke study's fixture

from cape.config import REPO_ROOT
from cape.study.reports.outputs import STUDY_NOTEBOOKS, WHOLE_STUDY_NOTEBOOKS

SNAKEFILE = REPO_ROOT / "Snakefile"
CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")


def _snakemake(
    *args: str, cwd: Path = REPO_ROOT, timeout: float = 600
) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        ["snakemake", "-s", str(SNAKEFILE), *args],
        cwd=cwd,
        capture_output=True,
        text=True,
        timeout=timeout,
    )


def _digest(data: bytes) -> str:
    return hashlib.sha256(data).hexdigest()[:16]


def _shown_pngs(notebook: Path) -> list[bytes]:
    """The PNG images an executed notebook shows, in order."""
    cells = json.loads(notebook.read_text())["cells"]
    outputs = [o for c in cells for o in c.get("outputs", [])]
    pngs = [o["data"]["image/png"] for o in outputs if "image/png" in o.get("data", {})]
    return [base64.b64decode(png) for png in pngs]


class _Page(HTMLParser):
    """An HTML copy as a reader gets it: its visible text and its embedded PNG images."""

    def __init__(self, text: str) -> None:
        super().__init__()
        self.text: list[str] = []
        self.pngs: list[bytes] = []
        self._hidden = 0
        self.feed(text)

    def handle_starttag(self, tag: str, attrs: list[tuple[str, str | None]]) -> None:
        self._hidden += tag in ("style", "script")
        src = dict(attrs).get("src") or ""
        if tag == "img" and src.startswith("data:image/png;base64,"):
            self.pngs.append(base64.b64decode(src.split(",", 1)[1]))

    def handle_endtag(self, tag: str) -> None:
        self._hidden -= tag in ("style", "script")

    def handle_data(self, data: str) -> None:
        if not self._hidden:
            self.text.append(data)


def _png_size(path: Path) -> tuple[int, int]:
    header = path.read_bytes()[16:24]  # IHDR: width, height
    return int.from_bytes(header[:4], "big"), int.from_bytes(header[4:], "big")


def test_lint_is_clean() -> None:
    result = _snakemake("--lint")
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Congratulations" in result.stdout + result.stderr


def test_dry_run_plans_every_target() -> None:
    result = _snakemake("-n", "--cores", "2", "--forceall")
    assert result.returncode == 0, result.stderr
    out = result.stdout + result.stderr
    for rule in ("tracks", "dataset", "figure_tracks", "all"):
        assert rule in out


def _planned_commands(*configfiles: str) -> dict[str, str]:
    """Each planned job's output → its shell command (which carries its --config-json), from a
    forced dry run of a few runs and their solvers and networks."""
    runs = [
        "results/runs/learned/rep0/ddm/ddm/anmpc/eta1/seed0/metrics.json",
        "results/runs/truth/rep0/truth/truth/nmpc/eta1/seed0/metrics.json",
        "results/runs/truth/rep0/truth/epm/rnmpc/eta1/seed0/metrics.json",
    ]
    files = [str(REPO_ROOT / f) for f in configfiles]
    result = _snakemake("-n", "-p", "--forceall", "--cores", "2", *runs, "--configfile", *files)
    assert result.returncode == 0, result.stdout + result.stderr
    commands, output = {}, None
    for line in result.stdout.splitlines():
        if line.strip().startswith("output:"):
            output = line.split("output:", 1)[1].split(",")[0].strip()
        elif line.startswith("Shell command: cape ") and output is not None:
            commands[output] = line.removeprefix("Shell command: ")
    return commands


def test_adding_a_model_reruns_no_other_models_jobs() -> None:
    """A model added by its config entry changes no other run's, solver's or network's command
    (their --config-json holds only the models they read), so Snakemake reruns none of them."""
    before = _planned_commands("config/config.yaml")
    after = _planned_commands("config/config.yaml", "config/examples/epm_network_ddm_physics.yaml")
    assert any("cape rollout" in c for c in before.values())
    assert any("cape build-solver" in c for c in before.values())
    assert any("cape export-network" in c for c in before.values())
    assert set(after) >= set(before)
    changed = [out for out, command in before.items() if after[out] != command]
    assert changed == []
    assert "epmnet" not in " ".join(before.values())


def test_data_targets_build_and_match_fingerprints(tmp_path: Path) -> None:
    import numpy as np

    work = _workdir(tmp_path)
    targets = ["results/data/DYN-PP-ETHZ.npz", "results/data/DYN-PP-ETHZMobil.npz"]
    result = _snakemake("--cores", "2", "-d", str(work), *targets)
    assert result.returncode == 0, result.stdout + result.stderr
    with np.load(work / targets[0]) as ethz:
        np.testing.assert_allclose(ethz["inputs"][:, 999], [-0.0054280906, -0.1095121], atol=1e-9)
    # a second run has nothing to do
    again = _snakemake("--cores", "2", "-d", str(work), *targets)
    assert "Nothing to be done" in again.stdout + again.stderr


def test_no_mirror_and_no_network_fails_with_the_clear_message(tmp_path: Path) -> None:
    work = _workdir(
        tmp_path, mirror=str(tmp_path / "absent"), upstream_url="http://127.0.0.1:9/{file}"
    )
    result = _snakemake("--cores", "1", "-d", str(work), "results/data/DYN-PP-ETHZ.npz")
    out = result.stdout + result.stderr
    assert result.returncode != 0
    assert "cannot obtain track file" in out
    assert "tracks.mirror" in out and "upstream commit" in out
    assert not (work / "results" / "data" / "DYN-PP-ETHZ.npz").exists()


@pytest.mark.skipif(shutil.which("ruff") is None, reason="ruff is installed by requirements.txt")
def test_code_is_ruff_clean() -> None:
    result = subprocess.run(
        ["ruff", "check", "src", "tests", "benchmarks"],
        cwd=REPO_ROOT,
        capture_output=True,
        text=True,
    )
    assert result.returncode == 0, result.stdout


def test_smoke_config_builds_the_model_tables(tmp_path: Path) -> None:
    """Two-epoch training of every model through the real rules, then both model tables."""
    import pandas as pd

    work = _workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    targets = [
        "results/tables/rep0/table01_model_complexity.csv",
        "results/tables/rep0/table04_openloop_rmse.csv",
    ]
    result = _snakemake(
        "--cores", "2", "-d", str(work), *targets, "--configfile", "config/smoke.yaml"
    )
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    complexity = pd.read_csv(work / targets[0])
    assert list(complexity["model"]) == ["dpm", "ddm", "epm"]
    assert complexity["params_M"].tolist() == pytest.approx(
        [0.028851, 2.878035, 0.917828], abs=1e-6
    )
    openloop = pd.read_csv(work / targets[1])
    assert (
        (openloop.filter(like="rmse").drop(columns=openloop.filter(like="paper").columns) > 0)
        .all()
        .all()
    )


def _checkout(where: Path) -> Path:
    """A copy of the workflow's files (Snakefile, rules, notebooks, config, profiles) at
    ``where``, as a checkout there would have them (the package is the installed one)."""
    for name in ("Snakefile", "workflow", "notebooks", "config", "profiles"):
        source = REPO_ROOT / name
        if source.is_dir():
            shutil.copytree(source, where / name, ignore=shutil.ignore_patterns("__pycache__"))
        else:
            where.mkdir(parents=True, exist_ok=True)
            shutil.copy(source, where / name)
    return where


def test_the_setup_notebook_shows_the_figure_and_tables_it_saves(tmp_path: Path) -> None:
    """Through the real rule (papermill, then nbconvert), from a checkout whose path has a
    space (every path reaching a shell is quoted): the executed notebook holds the saved PNG
    itself, at 100 pixels per figure inch, and each table as its saved .md prints it; the HTML
    copy embeds the same image; the config reaches it as a job specification file of just
    the sections it reads."""
    checkout = _checkout(tmp_path / "my projects" / "cape")
    work = _workdir(tmp_path / "my projects")
    result = subprocess.run(
        ["snakemake", "-s", str(checkout / "Snakefile"), "--cores", "1", "-d", str(work),
         "results/notebooks/setup.html"], capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    notebook = work / "results/notebooks/setup.ipynb"
    figure = work / "results/figures/fig01_block_diagram.png"
    assert [_digest(p) for p in _shown_pngs(notebook)] == [_digest(figure.read_bytes())]
    outputs = [o for c in json.loads(notebook.read_text())["cells"] for o in c.get("outputs", [])]
    image = next(o for o in outputs if "image/png" in o.get("data", {}))
    assert image["metadata"]["image/png"]["width"] == round(_png_size(figure)[0] / 2)  # 200 dpi
    shown_tables = [o["data"]["text/plain"] for o in outputs if "text/html" in o.get("data", {})]
    saved_tables = [
        (work / f"results/tables/{name}.md").read_text()
        for name in WHOLE_STUDY_NOTEBOOKS["setup"].tables
    ]
    assert ["".join(t) for t in shown_tables] == saved_tables
    page = _Page((work / "results/notebooks/setup.html").read_text())
    assert [_digest(p) for p in page.pngs] == [_digest(figure.read_bytes())]
    text = "".join(page.text)
    # the notebook's job specification: a short path, the file holding just its sections
    spec = re.search(r'spec = "(results/specs/notebook_setup/[0-9a-f]{16}\.json)"', text)
    assert spec is not None, text[:2000]
    assert sorted(json.loads((work / spec.group(1)).read_text())) == [
        "controllers", "disturbances", "models"
    ]  # fmt: skip
    assert "Study set-up" in text and "Table 3" in text  # ... and the rest of the page


SCHEDULER_THREADS = 40
"""The most threads the `snakemake` process may hold (docs/cluster.md): it held 139 on the smoke
study and 660 to 785 on the replicated one before its wake-up timers were bounded."""


@pytest.mark.slow
def test_snakemake_holds_a_bounded_number_of_threads(smoke_study: Path) -> None:
    """Snakemake 9.27 starts a timer thread on every pass of its scheduler; CAPE keeps one
    pending (cape/workflow/scheduler.py), so the smoke study's 300-odd jobs leave the
    process with a few threads, not hundreds."""
    from conftest import SMOKE_THREADS

    (threads,) = SMOKE_THREADS
    if threads is None:
        pytest.skip("no /proc to read a thread count from")
    assert 0 < threads < SCHEDULER_THREADS


def test_a_refused_wakeup_thread_wakes_the_scheduler_at_once(monkeypatch) -> None:
    """A machine that will not start the timer's thread (ulimit -u reached) slows the
    scheduler for a moment, never crashes it."""
    import threading

    from snakemake.scheduling.job_scheduler import JobScheduler

    from cape.workflow import scheduler

    assert scheduler.bound_wakeup_timers()

    class Loop:
        _open_jobs = threading.Semaphore(0)

    def refuse(self: threading.Thread) -> None:
        raise RuntimeError("can't start new thread")

    monkeypatch.setattr(threading.Timer, "start", refuse)
    loop = Loop()
    JobScheduler._schedule_reevalutation(loop, 0.01)
    assert loop._open_jobs.acquire(timeout=2)  # woken, and a later pass may try again
    assert not loop.__dict__["_cape_timer_pending"]


def test_one_timer_is_pending_however_often_a_pass_asks(monkeypatch) -> None:
    import threading

    from snakemake.scheduling.job_scheduler import JobScheduler

    from cape.workflow import scheduler

    assert scheduler.bound_wakeup_timers()

    class Loop:
        _open_jobs = threading.Semaphore(0)

    loop = Loop()
    before = threading.active_count()
    for _ in range(200):
        JobScheduler._schedule_reevalutation(loop, 0.3)
    assert threading.active_count() - before <= 1
    assert loop._open_jobs.acquire(timeout=5)  # the one timer wakes the loop
    assert not loop._open_jobs.acquire(timeout=0.5)  # and only once
    JobScheduler._schedule_reevalutation(loop, 0.01)  # after it fired, a pass sets a new one
    assert loop._open_jobs.acquire(timeout=5)


@pytest.mark.slow
def test_the_smoke_study_builds_every_table_figure_and_notebook(smoke_study: Path) -> None:
    """Every output of `snakemake` exists, every notebook ran, and every run of the grid is in
    the aggregated table. CI runs this."""
    import pandas as pd

    work = smoke_study
    runs = pd.read_parquet(work / "results/study/runs.parquet")
    assert set(runs["study"]) == {"learned", "bicycle", "ablation", "truth"}
    # the smoke grid by hand (config/smoke.yaml; one seed; PID and RISE have no internal model):
    # learned 3 plants × 5 controllers × 2 η; bicycle 3 × 2 × 2; ablation 3 plants × 3 internal
    # × nominal NMPC × η 0; truth (PID + 2 NMPCs × 2 internal models) × 2 η
    expected = 3 * 5 * 2 + 3 * 2 * 2 + 3 * 3 * 1 * 1 + (1 + 2 * 2) * 2
    assert len(runs) == expected == 61 and runs["seed"].eq(0).all()
    assert runs["replicate"].eq(0).all()  # the default target's study: replicate 0
    # the replicates' scope adds, for replicate 1, the paper's study (3 plants × 5 × 2 η) and the
    # truth study (PID + 2 NMPCs × 2 internal models) × 2 η, all computed on replicate 1's own
    # seed (1000, SPEC §10 revision 7), the runs without a learned model too
    every = pd.read_parquet(work / "results/replicates/study/runs.parquet")
    assert len(every) == expected + 30 + 10
    learned = every.query("study == 'learned'")
    assert learned.groupby("replicate").size().to_dict() == {0: 30, 1: 30}
    assert every.query("study == 'truth'").groupby("replicate").size().to_dict() == {0: 10, 1: 10}
    assert every.query("study not in ('learned', 'truth')")["replicate"].eq(0).all()
    assert set(every.query("replicate == 1")["seed"]) == {1000}
    # the ablation's diagonal (internal = plant: 3 runs) is the learned study's, computed once;
    # replicate 1 computes all its 30 + 10 runs (before revision 7, 30 + 4: its truth runs with
    # no learned model were draw 0's, on draw 0's seed)
    computed = len(list((work / "results/runs").rglob("metrics.json")))
    assert computed == expected - 3 + 30 + 10
    table8 = pd.read_csv(work / "results/replicates/tables/table08_scorecard.csv")
    per_draw = {"verdict rep0 (this network)", "verdict rep1 (this network)", "effect rep1"}
    headline = "verdict (draws that trained)"
    beside = {"verdict FDR (draws that trained)", "verdict (every draw, failed trainings included)"}
    assert per_draw | beside | {headline, "p", "draws needed"} <= set(table8)
    papers = table8[table8["setting"] == "paper"]  # the ground-truth plant's need the adaptive NMPC
    assert set(papers[headline]) <= {"holds", "contradicted", "inconclusive"}
    # smoke DDM never trains (two epochs): its rows rest on no draw that trained and say so
    ddm = papers[papers["comparison"].str.contains("DDM") & papers["ours"].eq("–")]
    assert len(ddm) and ddm[headline].eq("inconclusive").all()
    glance = (work / "results/replicates/RESULTS.md").read_text()
    assert glance.index("## Holds over the training draws") < glance.index("## Runs")
    over = pd.read_csv(work / "results/replicates/tables/table04_replicates.csv")
    assert over["replicates"].eq(2).all() and "test_rmse_omega_sd" in over
    assert (work / "results/replicates/figures/fig13_claim_effects.png").stat().st_size > 10_000
    assert (work / "results/replicates/notebooks/scorecard.html").stat().st_size > 10_000
    assert (work / "results/models/rep1/epm/network.npz").is_file()
    assert "# CAPE results at a glance" in (work / "results/RESULTS.md").read_text()
    assert set(runs["eta_label"]) == {"0", "1"}
    figures = sorted((work / "results/figures").rglob("fig*.png"))
    numbers = {p.name[3:5] for p in figures}
    assert numbers == {f"{n:02d}" for n in range(1, 15)}, numbers  # figure 14: table 9's
    assert all(p.stat().st_size > 10_000 for p in figures)
    tables = {p.name[5:7] for p in (work / "results/tables").rglob("table*.md")}
    assert tables == {f"{n:02d}" for n in range(1, 10)}, tables  # table 9: the leaderboard
    studies = ("learned", "truth", "bicycle", "ablation")
    for name in ("setup", "scorecard", *studies, *(f"failures_{s}" for s in studies)):
        assert (work / "results/notebooks" / f"{name}.ipynb").is_file()
        assert (work / "results/notebooks" / f"{name}.html").stat().st_size > 10_000
    # the default target's one draw: its verdicts say they are this draw's
    scorecard = pd.read_csv(work / "results/tables/table08_scorecard.csv")
    assert {"paper", "ours", "ci95_low", "ci95_high", "verdict (this training draw)"} <= set(
        scorecard
    )
    assert not any(c.startswith("verdict rep") for c in scorecard)
    one = (work / "results/RESULTS.md").read_text()
    assert "## Holds for this training draw" in one and "snakemake --cores 2 replicates" in one


def _smoke_notebooks(work: Path) -> dict[str, tuple[Path, tuple[str, ...]]]:
    """Each executed notebook of the smoke study → the folder of its figures and the figures
    it declares (cape.study.reports.outputs), in order."""
    config = yaml.safe_load((work / "config" / "config.yaml").read_text())
    smoke = yaml.safe_load((work / "config" / "smoke.yaml").read_text())
    figures = work / "results" / "figures"
    out = {
        "setup": (figures, tuple(WHOLE_STUDY_NOTEBOOKS["setup"].figures)),
        "scorecard": (figures, tuple(WHOLE_STUDY_NOTEBOOKS["scorecard"].figures)),
    }
    for study, grid in config["study"]["studies"].items():
        kind = {**grid, **smoke["study"]["studies"].get(study, {})}.get("kind", "closed_loop")
        out[study] = (figures / study, tuple(STUDY_NOTEBOOKS[kind].figures))
        out[f"failures_{study}"] = (figures / study, tuple(STUDY_NOTEBOOKS["failures"].figures))
    return out


@pytest.mark.slow
def test_every_smoke_notebook_shows_each_figure_it_saves(smoke_study: Path) -> None:
    """Each executed notebook holds, in order, the very PNG files of the figures it declares,
    and its HTML copy embeds them."""
    notebooks = _smoke_notebooks(smoke_study)
    assert len(notebooks) == 10
    for name, (folder, figures) in notebooks.items():
        saved = [_digest((folder / f"{figure}.png").read_bytes()) for figure in figures]
        shown = [_digest(p) for p in _shown_pngs(smoke_study / f"results/notebooks/{name}.ipynb")]
        page = _Page((smoke_study / f"results/notebooks/{name}.html").read_text())
        assert shown == saved, name
        assert [_digest(p) for p in page.pngs] == saved, name
    assert sum(len(figures) for _, figures in notebooks.values()) == 24  # 1 + 2 × 7 + 2 + 1 + 4 + 2
    # and the replicates' scorecard, from its own folder
    scope = smoke_study / "results" / "replicates"
    saved = [
        _digest((scope / "figures" / f"{f}.png").read_bytes()) for f in notebooks["scorecard"][1]
    ]
    assert [_digest(p) for p in _shown_pngs(scope / "notebooks" / "scorecard.ipynb")] == saved


@pytest.mark.slow
@pytest.mark.skipif(
    CHROMIUM is None, reason="no Chromium to open the page in (Debian: apt-get install chromium)"
)
def test_a_notebook_page_shows_its_figures_in_a_real_browser(
    smoke_study: Path, tmp_path: Path
) -> None:
    """learned.html in headless Chromium: every figure decodes to the saved PNG's size and is
    laid out at a size that reads (not collapsed, not wider than the window)."""
    assert CHROMIUM is not None
    # the page as it is, plus a script that, once everything has loaded, writes each image's
    # decoded and laid-out size into the page, which --dump-dom then prints
    probe = (
        "<script>window.addEventListener('load', () => {"
        " const sizes = [...document.images].map("
        "  i => [i.naturalWidth, i.naturalHeight, i.clientWidth, i.clientHeight]);"
        " const out = document.createElement('pre'); out.id = 'cape-image-sizes';"
        " out.textContent = JSON.stringify(sizes); document.body.appendChild(out); });</script>"
    )
    text = (smoke_study / "results/notebooks/learned.html").read_text()
    page = tmp_path / "learned.html"
    page.write_text(text.replace("</body>", probe + "</body>"))
    width = 1400
    # the flags of a closed network: no background connection Chromium would wait for
    command = [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic",
               "--no-first-run", "--disable-background-networking", "--disable-component-update",
               "--disable-sync", f"--user-data-dir={tmp_path / 'profile'}",
               f"--window-size={width},1000", "--dump-dom", page.as_uri()]  # fmt: skip
    result = subprocess.run(command, capture_output=True, text=True, timeout=300)
    found = re.search(r'<pre id="cape-image-sizes">(.*?)</pre>', result.stdout)
    assert found, result.stdout[-2000:] + result.stderr[-2000:]
    sizes = json.loads(html.unescape(found.group(1)))
    figures = STUDY_NOTEBOOKS["closed_loop"].figures
    assert len(sizes) == len(figures)
    for (natural_w, natural_h, shown_w, shown_h), name in zip(sizes, figures, strict=True):
        saved = smoke_study / f"results/figures/learned/{name}.png"
        assert (natural_w, natural_h) == _png_size(saved), name
        assert 300 <= shown_w <= width and shown_h > 0, (name, shown_w, shown_h)


@pytest.mark.slow
def test_a_damaged_run_stops_what_reads_it_and_is_recomputed_once_deleted(
    smoke_study: Path, tmp_path: Path
) -> None:
    """A truncated time series in a copy of the smoke study: the aggregation and the notebook
    that draws the run each stop with one message naming the run's folder and the fix; the
    notebook leaves no `.part.ipynb` among the results (its executed copy goes beside its log);
    the fix the message gives (`snakemake --force` of the run's metrics.json: no `rm`, issue 61)
    recomputes the run, and the notebook then draws it."""
    work = tmp_path / "copy"
    shutil.copytree(smoke_study, work, symlinks=True)
    folder = work / "results/runs/learned/rep0/epm/epm/pid/eta0/seed0"
    series = folder / "timeseries.parquet"
    series.write_bytes(series.read_bytes()[:3000])
    rel_folder, rel_series = folder.relative_to(work), series.relative_to(work)  # as jobs name them
    common = ["--cores", "1", "-d", str(work), "--configfile", "config/smoke.yaml"]
    drawn = _snakemake(*common, "-f", "results/notebooks/learned.html", timeout=600)
    log = (work / "results/logs/notebooks/learned.log").read_text()
    assert drawn.returncode != 0 and str(rel_folder) in log and "truncated, damaged" in log, log
    assert not list((work / "results/notebooks").glob("*.part.ipynb"))
    assert (work / "results/logs/notebooks/learned.log.failed.ipynb").is_file()
    assert "its executed copy, with the failing cell: results/logs/notebooks/learned.log" in log
    aggregated = _snakemake(*common, "-f", "results/study/runs.parquet", timeout=600)
    log = (work / "results/logs/study/aggregate.log").read_text()
    assert aggregated.returncode != 0 and str(rel_series) in log, log
    fix = f"snakemake --cores 1 --force {rel_folder / 'metrics.json'}"
    assert fix in log and "rm " not in log, log
    forced = _snakemake("--force", str(rel_folder / "metrics.json"), *common, timeout=900)
    assert forced.returncode == 0, forced.stdout[-3000:] + forced.stderr[-3000:]
    again = _snakemake("results/notebooks/learned.html", *common, timeout=900)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert (folder / "metrics.json").is_file() and (
        work / "results/notebooks/learned.html"
    ).is_file()


@pytest.mark.slow
def test_deleted_outputs_are_rebuilt_with_everything_downstream(
    smoke_study: Path, tmp_path: Path
) -> None:
    """In a copy of the smoke study, a model folder, runs, a table, a figure and a notebook
    deleted: rerunning the targets that contain them rebuilds each, and what depends on them
    (the model's exported network, its runs, the aggregation, the scorecard); runs.parquet
    lists exactly the runs there are. Asked for alone, runs.parquet says its runs are missing
    and which command rebuilds them."""
    import pandas as pd

    work = tmp_path / "copy"
    shutil.copytree(smoke_study, work, symlinks=True)
    common = ["--cores", "2", "-d", str(work), "--configfile", "config/smoke.yaml"]
    runs = sorted((work / "results/runs/learned/rep0").rglob("metrics.json"))[:3]
    for metrics in runs:
        shutil.rmtree(metrics.parent)
    direct = _snakemake("results/study/runs.parquet", "-n", *common, timeout=600)
    assert "results/study/runs.parquet: 3 of its runs are missing" in direct.stderr
    assert "`snakemake --cores 2 all` rebuilds them and it" in direct.stderr
    model = work / "results/models/rep1/dpm"
    network = (model / "network.npz").read_bytes()
    dpm_run = work / "results/runs/learned/rep1/dpm/dpm/pid/eta0/seed1000/metrics.json"
    deleted = [
        work / "results/tables/rep0/table04_openloop_rmse.md",
        work / "results/figures/tracks_and_data.png",
        work / "results/notebooks/setup.html",
        work / "results/replicates/tables/table08_scorecard.csv",
    ]
    shutil.rmtree(model)
    for path in deleted:
        path.unlink()
    before = dpm_run.stat().st_mtime
    again = _snakemake("all", "replicates", *common, timeout=1500)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    assert all(p.is_file() for p in deleted) and (model / "model.pt").is_file()
    assert (model / "network.npz").read_bytes() == network  # the same seed: the same network
    assert dpm_run.stat().st_mtime > before  # its runs were recomputed on the new files
    assert all(m.is_file() for m in runs)
    table = pd.read_parquet(work / "results/study/runs.parquet")
    assert len(table) == len(pd.read_parquet(smoke_study / "results/study/runs.parquet"))
    assert all((work / folder / "metrics.json").is_file() for folder in table["folder"])
    nothing = _snakemake("all", "replicates", "-n", *common, timeout=600)
    assert "Nothing to be done" in nothing.stdout + nothing.stderr


@pytest.mark.slow
def test_notebooks_with_nothing_to_draw_say_so_and_write_their_outputs(tmp_path: Path) -> None:
    """Through the real `snakemake`: the learned, bicycle and ablation studies limited to
    replicate 1 leave the default target (replicate 0) nothing of theirs to draw; every notebook
    still runs, each figure and table it declares says why it is empty and which command
    computes the runs, and RESULTS.md lists the paper's closed-loop claims as not evaluated.
    Then `study.paper` naming a study without the claims' runs: the same rows, another why."""
    work = _workdir(tmp_path)
    shutil.copy(REPO_ROOT / "config" / "smoke.yaml", work / "config" / "smoke.yaml")
    elsewhere = {s: {"replicates": [1]} for s in ("learned", "bicycle", "ablation")}
    elsewhere["truth"] = {"internal": ["truth"], "controllers": ["pid"]}
    (work / "config" / "rep1.yaml").write_text(yaml.safe_dump({"study": {"studies": elsewhere}}))
    (work / "config" / "paper.yaml").write_text(yaml.safe_dump({"study": {"paper": "truth"}}))
    common = ["--cores", "2", "-d", str(work), "--configfile", "config/smoke.yaml"]
    rep1, paper = str(work / "config" / "rep1.yaml"), str(work / "config" / "paper.yaml")
    result = _snakemake("all", *common, rep1, timeout=1500)
    assert result.returncode == 0, result.stdout[-3000:] + result.stderr[-3000:]
    why = "this target holds no run of the learned study, which runs for training draw(s) 1"
    for name, study in (("learned", "learned"), ("bicycle", "bicycle"), ("ablation", "ablation")):
        cells = json.loads((work / f"results/notebooks/{name}.ipynb").read_text())["cells"]
        printed = "".join("".join(o.get("text", "")) for c in cells for o in c.get("outputs", []))
        assert f"Nothing to draw: this target holds no run of the {study} study" in printed
        for figure in STUDY_NOTEBOOKS[name.replace("learned", "closed_loop")].figures:
            assert (work / f"results/figures/{study}/{figure}.png").is_file(), figure
    table6 = (work / "results/tables/learned/table06_metrics_eta1.md").read_text()
    assert "nothing to show" in table6 and why in table6
    glance = (work / "results/RESULTS.md").read_text()
    assert "## Not evaluated:" in glance
    assert f"EPM − DDM: not evaluated: {why}" in glance
    assert "not evaluated: no run of DPM-fixed in a bicycle study of this target" in glance
    again = _snakemake("results/RESULTS.md", *common, rep1, paper)
    assert again.returncode == 0, again.stdout[-3000:] + again.stderr[-3000:]
    glance = (work / "results/RESULTS.md").read_text()
    assert "EPM − DDM: not evaluated: the paper's study has no runs of anmpc" in glance

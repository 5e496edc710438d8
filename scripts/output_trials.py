#!/usr/bin/env python3
"""Black-box trials of omnicml's output side (docs/results.md "Trustworthy outputs").

  scripts/output_trials.py [--binary build/omnicml] [--trials N] [--only CLASS ...]

Classes (each prints one summary line, counts only):
  substitutions  every output flag of every command, run for real, against a FIFO, a
                 socket, a directory or regular file, symbolic links and (as root) a
                 character device made in a private directory: the command must exit 2
                 with one line naming the path and leave the node as it was; a control
                 run with a plain new path must succeed.
  follow         every output file flag again with the global --follow-output-symlinks:
                 a symbolic link to a regular file is written through (exit 0, the link
                 stays, the file it leads to is replaced); links to a FIFO, a directory
                 or nothing and the other non-regular nodes are still refused.
  kill           `run --out R --map-out M --trajectory-out T` killed with SIGKILL at
                 seeded random moments over an earlier complete run: afterwards R, M and
                 T are all the old run or all the new one (by SHA-256 and R/outputs.yaml),
                 and the next run leaves no debris (staging, temporaries, lock files).
  window         the same run killed by the test hook OMNICML_TEST_KILL_AT inside its
                 commit: between the map/trajectory renames and the run-directory swap
                 ("staged-commit-swap", a mix is on disk) or just after the swap
                 ("staged-commit-settle"); then the next writer, killed at a random moment
                 of its run, must leave an old-or-new state (it settles the interrupted
                 commit when it starts), and a last complete run no debris.
  diskfull       the same run on a small tmpfs (root only) with the free space cut at
                 seeded levels: it succeeds or exits 2; the state is old or new, nothing
                 mixed, no staging directory or temporary left.
  writers        two writers of the same outputs at once (run, simulate --overwrite,
                 sweep): the second refuses with exit 2 naming the path and the holder's
                 pid; the first completes.
  sweep          `omnicml sweep` killed (SIGKILL to its process group, SIGTERM, SIGINT)
                 at seeded random moments, then rerun: every rerun completes with every
                 job collected, and no Snakemake or job process outlives its sweep.

Nodes are created in private temporary directories; /dev/null and the like are never
passed to a command.
"""
import argparse
import hashlib
import os
import random
import shutil
import signal
import socket
import stat
import subprocess
import sys
import tempfile
import time

HERE = os.path.dirname(os.path.abspath(__file__))
ROOT = os.path.dirname(HERE)


def sha256(path):
    h = hashlib.sha256()
    with open(path, "rb") as f:
        for chunk in iter(lambda: f.read(1 << 20), b""):
            h.update(chunk)
    return h.hexdigest()


def fingerprint(path):
    try:
        st = os.lstat(path)
    except FileNotFoundError:
        return "missing"
    out = "%o:%d" % (stat.S_IFMT(st.st_mode), st.st_ino)
    if stat.S_ISLNK(st.st_mode):
        target = os.readlink(path)
        out += "->" + target
        if os.path.isfile(target):
            out += "=" + sha256(target)
        elif os.path.isdir(target):
            out += "=dir:" + ",".join(sorted(os.listdir(target)))
    elif stat.S_ISDIR(st.st_mode):
        out += "=dir:" + ",".join(sorted(os.listdir(path)))
    elif stat.S_ISREG(st.st_mode):
        out += "=" + sha256(path)
    return out


def run(args, cwd=None, timeout=600):
    p = subprocess.run(args, cwd=cwd, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                       timeout=timeout)
    return p.returncode, p.stdout.decode(errors="replace"), p.stderr.decode(errors="replace")


def debris(top):
    """Staging directories, temporaries and lock files under `top`."""
    found = []
    for dirpath, dirnames, filenames in os.walk(top):
        for name in dirnames + filenames:
            if (".partial-" in name or ".old-" in name or ".omnicml-tmp-" in name
                    or name.endswith(".omnicml-lock") or ".omnicml-prev-" in name
                    or name == ".omnicml-commit"):
                found.append(os.path.join(dirpath, name))
    return found


# ---------------------------------------------------------------------------------------
# substitutions

def make_nodes(d, directory_output):
    """(kind, path) of non-regular nodes in d that an output must refuse."""
    nodes = []
    fifo = os.path.join(d, "fifo")
    os.mkfifo(fifo)
    nodes.append(("fifo", fifo))
    sock = os.path.join(d, "sock")
    s = socket.socket(socket.AF_UNIX)
    s.bind(sock)
    s.close()
    nodes.append(("socket", sock))
    real = os.path.join(d, "real.txt")
    with open(real, "w") as f:
        f.write("precious\n")
    realdir = os.path.join(d, "realdir")
    os.mkdir(realdir)
    with open(os.path.join(realdir, "keep.txt"), "w") as f:
        f.write("precious\n")
    link_file = os.path.join(d, "link_file")
    os.symlink(real, link_file)
    nodes.append(("symlink to a regular file", link_file))
    link_dir = os.path.join(d, "link_dir")
    os.symlink(realdir, link_dir)
    nodes.append(("symlink to a directory", link_dir))
    dangling = os.path.join(d, "dangling")
    os.symlink(os.path.join(d, "nowhere"), dangling)
    nodes.append(("dangling symlink", dangling))
    if directory_output:
        nodes.append(("regular file", real))
    else:
        nodes.append(("directory", realdir))
    if os.geteuid() == 0:
        dev = os.path.join(d, "null")
        os.mknod(dev, 0o666 | stat.S_IFCHR, os.makedev(1, 3))
        nodes.append(("character device", dev))
    return nodes


def substitution_cases(binary, work):
    """(command label, flag, is_directory, argv builder(path)) for every output flag."""
    fixtures = os.path.join(work, "fixtures")
    os.makedirs(fixtures)
    run_dir = os.path.join(fixtures, "run")
    map_path = os.path.join(fixtures, "map.omnicml")
    code, _, err = run([binary, "run", "--world", "home_store", "--frames-per-day", "40",
                        "--quiet", "--out", run_dir, "--map-out", map_path])
    assert code == 0, err
    log_dir = os.path.join(fixtures, "log")
    code, _, err = run([binary, "simulate", "--world", "home_store", "--frames-per-day", "3",
                        "--out", log_dir])
    assert code == 0, err
    raw = sorted(p for p in os.listdir(os.path.join(log_dir, "day_001")) if p.endswith(".png"))[0]
    raw = os.path.join(log_dir, "day_001", raw)
    spec = os.path.join(fixtures, "spec.yaml")
    with open(spec, "w") as f:
        f.write("command: run\ninputs:\n  - {world: home_store, days: 1, frames_per_day: 10, "
                "name: hs}\nseeds: [1]\n")
    antworld = "/work/shared/datasets/antworld/ant1_route1"
    antworld_csv = None
    if os.path.isdir(antworld):
        csvs = [f for f in os.listdir(antworld) if f.endswith(".csv")]
        if csvs:
            antworld_csv = os.path.join(antworld, sorted(csvs)[0])
    sim = ["--world", "home_store", "--frames-per-day", "20", "--quiet"]
    cases = [
        ("run", "--out", True, lambda p: [binary, "run"] + sim + ["--out", p]),
        ("run", "--map-out", False,
         lambda p: [binary, "run"] + sim + ["--out", os.path.join(os.path.dirname(p), "r"),
                                            "--map-out", p]),
        ("run", "--trajectory-out", False,
         lambda p: [binary, "run"] + sim + ["--out", os.path.join(os.path.dirname(p), "r"),
                                            "--trajectory-out", p]),
        ("compare", "--out", True,
         lambda p: [binary, "compare", "--world", "home_store", "--frames-per-day", "10",
                    "--quiet", "--steps", "5", "--out", p]),
        ("simulate", "--out", True,
         lambda p: [binary, "simulate", "--world", "home_store", "--frames-per-day", "2",
                    "--out", p]),
        ("simulate", "--preview", False,
         lambda p: [binary, "simulate", "--world", "home_store", "--frames-per-day", "2",
                    "--out", os.path.join(os.path.dirname(p), "sim"), "--preview", p]),
        ("export", "--out", False, lambda p: [binary, "export", map_path, "--format", "png",
                                              "--out", p]),
        ("calibrate", "--out", False,
         lambda p: [binary, "calibrate", "--world", "home_store", "--frames-per-day", "40",
                    "--out", p]),
        ("lap-bound", "--csv", False,
         lambda p: [binary, "lap-bound", "--world", "home_store", "--samples", "0", "--csv", p]),
        ("evaluate", "--html", False, lambda p: [binary, "evaluate", run_dir, "--html", p]),
        ("unwrap", "--out", False,
         lambda p: [binary, "unwrap", raw, "--auto-calibrate", "--out", p]),
        ("unwrap", "--save-calibration", False,
         lambda p: [binary, "unwrap", raw, "--auto-calibrate", "--out",
                    os.path.join(os.path.dirname(p), "pano.png"), "--save-calibration", p]),
        ("describe", "--make-sample", True, lambda p: [binary, "describe", "--make-sample", p]),
        ("topo", "--out", True,
         lambda p: [binary, "topo", "--world", "home_store", "--days", "2", "--frames-per-day",
                    "60", "--train-day", "1", "--test-day", "2", "--out", p]),
        ("mcl", "--out", True,
         lambda p: [binary, "mcl", "--world", "home_store", "--days", "2", "--frames-per-day",
                    "30", "--particles", "200", "--out", p]),
        ("sweep", "--out", True, lambda p: [binary, "sweep", spec, "--out", p, "--no-run"]),
    ]
    if antworld_csv:
        cases.append(("import antworld", "--out", True,
                      lambda p: [binary, "import", "antworld", antworld_csv, "--stride", "50",
                                 "--out", p]))
    return cases


def trial_substitutions(binary, work, _rng, _n):
    cases = substitution_cases(binary, work)
    total = refused = controls_ok = 0
    problems = []
    per_command = {}
    for index, (command, flag, directory, argv) in enumerate(cases):
        d = os.path.join(work, "sub%02d" % index)
        os.makedirs(d)
        nodes = make_nodes(d, directory)
        for kind, path in nodes:
            before = fingerprint(path)
            code, _, err = run(argv(path))
            total += 1
            lines = [l for l in err.splitlines() if l.strip()]
            ok = code == 2 and len(lines) == 1 and path in lines[0] and fingerprint(path) == before
            per_command.setdefault(command + " " + flag, [0, 0])
            per_command[command + " " + flag][1] += 1
            if ok:
                refused += 1
                per_command[command + " " + flag][0] += 1
            else:
                problems.append("%s %s (%s): exit %d, %r, changed=%s" % (
                    command, flag, kind, code, err[-300:], fingerprint(path) != before))
        control = os.path.join(d, "control_out" + ("" if directory else ".png"))
        if command == "calibrate" or flag == "--save-calibration":
            control = os.path.join(d, "control.yaml")
        if flag == "--csv":
            control = os.path.join(d, "control.csv")
        if flag == "--html":
            control = os.path.join(d, "control.html")
        if flag == "--trajectory-out":
            control = os.path.join(d, "control.tum")
        if flag == "--map-out":
            control = os.path.join(d, "control.omnicml")
        code, _, err = run(argv(control))
        if code == 0:
            controls_ok += 1
        else:
            problems.append("control %s %s: exit %d %s" % (command, flag, code, err[-300:]))
    for key, (ok, n) in sorted(per_command.items()):
        print("  %-28s %d/%d refused" % (key, ok, n))
    print("substitutions: %d/%d refused (exit 2, one line naming the path, node unchanged); "
          "writes through a non-regular path: %d; controls with a plain path: %d/%d succeeded"
          % (refused, total, total - refused, controls_ok, len(cases)))
    for p in problems:
        print("  PROBLEM:", p)
    return not problems


def trial_follow(binary, work, _rng, _n):
    cases = [c for c in substitution_cases(binary, work) if not c[2]]
    written = follow_total = refused = refuse_total = 0
    problems = []
    for index, (command, flag, _directory, argv) in enumerate(cases):
        d = os.path.join(work, "follow%02d" % index)
        os.makedirs(d)
        suffix = {"--csv": ".csv", "--html": ".html", "--trajectory-out": ".tum",
                  "--map-out": ".omnicml"}.get(flag, ".png")
        if command == "calibrate" or flag == "--save-calibration":
            suffix = ".yaml"
        real = os.path.join(d, "real" + suffix)
        with open(real, "w") as f:
            f.write("old\n")
        link = os.path.join(d, "link" + suffix)
        os.symlink(real, link)
        # evaluate refuses to replace an existing file without --force (the link leads to one).
        force = ["--force"] if command == "evaluate" else []
        code, _, err = run([argv(link)[0], "--follow-output-symlinks"] + argv(link)[1:] + force)
        follow_total += 1
        if code == 0 and os.path.islink(link) and open(real, "rb").read() != b"old\n":
            written += 1
        else:
            problems.append("%s %s through a link: exit %d, link kept %s, %r" % (
                command, flag, code, os.path.islink(link), err[-300:]))
        nodes_dir = os.path.join(d, "nodes")
        os.makedirs(nodes_dir)
        for kind, path in make_nodes(nodes_dir, False):
            if kind == "symlink to a regular file":
                continue
            before = fingerprint(path)
            code, _, err = run([argv(path)[0], "--follow-output-symlinks"] + argv(path)[1:])
            refuse_total += 1
            lines = [l for l in err.splitlines() if l.strip()]
            if code == 2 and len(lines) == 1 and path in lines[0] and fingerprint(path) == before:
                refused += 1
            else:
                problems.append("%s %s (%s) with --follow-output-symlinks: exit %d %r" % (
                    command, flag, kind, code, err[-300:]))
    print("--follow-output-symlinks: %d/%d output file flags wrote through a link to a regular "
          "file (link kept); %d/%d other non-regular paths still refused"
          % (written, follow_total, refused, refuse_total))
    for p in problems:
        print("  PROBLEM:", p)
    return not problems


# ---------------------------------------------------------------------------------------
# kill -9 and disk full

RUN_ARGS = ["--world", "home_store", "--frames-per-day", "120", "--days", "2", "--quiet"]


def run_argv(binary, top, seed):
    return [binary, "run"] + RUN_ARGS + ["--seed", str(seed), "--out", os.path.join(top, "run"),
                                         "--map-out", os.path.join(top, "map.omnicml"),
                                         "--trajectory-out", os.path.join(top, "traj.tum")]


def state_of(top):
    """('none' | (map sha, traj sha), consistent?) of the outputs in `top`."""
    run_dir = os.path.join(top, "run")
    paths = [os.path.join(top, "map.omnicml"), os.path.join(top, "traj.tum")]
    present = [os.path.exists(run_dir)] + [os.path.exists(p) for p in paths]
    if not any(present):
        return "none", True
    if not all(present):
        return "partial", False
    manifest = os.path.join(run_dir, "outputs.yaml")
    if not os.path.exists(manifest):
        return "no manifest", False
    text = open(manifest).read()
    shas = (sha256(paths[0]), sha256(paths[1]))
    consistent = all(("sha256: " + s) in text for s in shas)
    return shas, consistent


def trial_kill(binary, work, rng, n):
    top = os.path.join(work, "kill")
    os.makedirs(top)
    ref = {}
    for seed in (1, 2):
        ref_top = os.path.join(work, "kill_ref%d" % seed)
        os.makedirs(ref_top)
        t0 = time.time()
        code, _, err = run(run_argv(binary, ref_top, seed))
        assert code == 0, err
        ref[seed] = (state_of(ref_top)[0], time.time() - t0)
    duration = ref[2][1]
    counts = {"old": 0, "new": 0, "mixed": 0}
    debris_after_next = 0
    for trial in range(n):
        shutil.rmtree(top)
        os.makedirs(top)
        code, _, err = run(run_argv(binary, top, 1))  # the old state
        assert code == 0, err
        delay = rng.uniform(0.0, 1.15 * duration)
        p = subprocess.Popen(run_argv(binary, top, 2), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        time.sleep(delay)
        p.send_signal(signal.SIGKILL)
        p.wait()
        state, consistent = state_of(top)
        if consistent and state == ref[1][0]:
            counts["old"] += 1
        elif consistent and state == ref[2][0]:
            counts["new"] += 1
        else:
            counts["mixed"] += 1
            print("  MIXED after kill at %.2f s: %s" % (delay, state))
        code, _, err = run(run_argv(binary, top, 1))
        if code != 0 or debris(top) or state_of(top) != (ref[1][0], True):
            debris_after_next += 1
            print("  DEBRIS/FAIL after next run: exit %d %s %s" % (code, debris(top), err[-200:]))
    print("kill -9 during run --out --map-out --trajectory-out: %d trials (kill at U(0, %.1f s), "
          "a full run takes %.1f s): %d old, %d new, %d mixed; next run failed or left debris: %d"
          % (n, 1.15 * duration, duration, counts["old"], counts["new"], counts["mixed"],
             debris_after_next))
    return counts["mixed"] == 0 and debris_after_next == 0


def trial_window(binary, work, rng, n):
    top = os.path.join(work, "window")
    ref = {}
    for seed in (1, 2, 3):
        ref_top = os.path.join(work, "window_ref%d" % seed)
        os.makedirs(ref_top)
        t0 = time.time()
        code, _, err = run(run_argv(binary, ref_top, seed))
        assert code == 0, err
        ref[seed] = (state_of(ref_top)[0], time.time() - t0)
    duration = ref[3][1]
    names = {ref[1][0]: "old", ref[2][0]: "new", ref[3][0]: "next"}
    points = ["staged-commit-swap", "staged-commit-settle"]
    after_kill = {p: {} for p in points}
    after_next = {}
    final_bad = 0
    for trial in range(n):
        point = points[trial % 2]
        shutil.rmtree(top, ignore_errors=True)
        os.makedirs(top)
        code, _, err = run(run_argv(binary, top, 1))
        assert code == 0, err
        env = dict(os.environ, OMNICML_TEST_KILL_AT=point)
        p = subprocess.run(run_argv(binary, top, 2), env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
        assert p.returncode == -signal.SIGKILL, "the hook did not kill (exit %d)" % p.returncode
        state, consistent = state_of(top)
        label = names.get(state, "?") if consistent else "mixed"
        after_kill[point][label] = after_kill[point].get(label, 0) + 1
        # The next writer, killed at a random moment of its run.
        q = subprocess.Popen(run_argv(binary, top, 3), stdout=subprocess.DEVNULL,
                             stderr=subprocess.DEVNULL)
        time.sleep(rng.uniform(0.3, 1.1) * duration)
        q.send_signal(signal.SIGKILL)
        q.wait()
        state, consistent = state_of(top)
        label = names.get(state, "?") if consistent else "mixed"
        after_next[label] = after_next.get(label, 0) + 1
        if label in ("mixed", "?"):
            print("  MIXED after the next writer (killed): %s" % (state,))
        code, _, err = run(run_argv(binary, top, 1))
        if code != 0 or debris(top) or state_of(top) != (ref[1][0], True):
            final_bad += 1
            print("  DEBRIS/FAIL after a complete run: exit %d %s %s" % (code, debris(top),
                                                                         err[-200:]))
    fmt = lambda d: ", ".join("%d %s" % (v, k) for k, v in sorted(d.items()))
    print("kill inside the commit (test hook), %d trials: right after the kill: swap point %s; "
          "settle point %s; after the next writer (killed at U(0.3, 1.1) x %.1f s): %s; "
          "a complete run afterwards failed or left debris: %d"
          % (n, fmt(after_kill[points[0]]), fmt(after_kill[points[1]]), duration,
             fmt(after_next), final_bad))
    return "mixed" not in after_next and "?" not in after_next and final_bad == 0


def trial_diskfull(binary, work, rng, n):
    if os.geteuid() != 0:
        print("diskfull: skipped (needs root to mount a tmpfs)")
        return True
    mnt = os.path.join(work, "tmpfs")
    os.makedirs(mnt)
    subprocess.check_call(["mount", "-t", "tmpfs", "-o", "size=8m", "tmpfs", mnt])
    try:
        ref_top = os.path.join(work, "df_ref")
        os.makedirs(ref_top)
        code, _, err = run(run_argv(binary, ref_top, 2))
        assert code == 0, err
        new_state = state_of(ref_top)[0]
        new_bytes = sum(os.path.getsize(os.path.join(dp, f))
                        for dp, _, fs_ in os.walk(ref_top) for f in fs_)
        counts = {"old": 0, "new": 0, "mixed": 0, "exit2": 0, "exit_other": 0, "debris": 0}
        for trial in range(n):
            for name in os.listdir(mnt):
                path = os.path.join(mnt, name)
                shutil.rmtree(path) if os.path.isdir(path) else os.remove(path)
            code, _, err = run(run_argv(binary, mnt, 1))
            assert code == 0, err
            old_state = state_of(mnt)[0]
            st = os.statvfs(mnt)
            free = st.f_bavail * st.f_frsize
            # Leave between 0 and 1.3x what the new state needs (the old one stays until
            # the commit, so both must fit for the run to succeed).
            leave = int(rng.uniform(0.0, 1.3) * new_bytes)
            fill = max(0, free - leave)
            with open(os.path.join(mnt, "filler"), "wb") as f:
                try:
                    f.write(b"\0" * fill)
                except OSError:
                    pass
            code, _, err = run(run_argv(binary, mnt, 2))
            lines = [l for l in err.splitlines() if l.strip()]
            if code == 2 and len(lines) == 1:
                counts["exit2"] += 1
            elif code != 0:
                counts["exit_other"] += 1
                print("  EXIT %d: %s" % (code, err[-300:]))
            os.remove(os.path.join(mnt, "filler"))
            state, consistent = state_of(mnt)
            if consistent and state == old_state:
                counts["old"] += 1
            elif consistent and state == new_state:
                counts["new"] += 1
            else:
                counts["mixed"] += 1
                print("  MIXED: exit %d %s" % (code, err[-200:]))
            if debris(mnt):
                counts["debris"] += 1
                print("  DEBRIS:", debris(mnt))
        print("disk full (tmpfs, free space U(0, 1.3) x the %d bytes of a run's outputs): %d "
              "trials: %d failed with exit 2 (one line), %d other failures; state %d old, %d new, "
              "%d mixed; debris left: %d" % (new_bytes, n, counts["exit2"], counts["exit_other"],
                                             counts["old"], counts["new"], counts["mixed"],
                                             counts["debris"]))
        return counts["mixed"] == 0 and counts["debris"] == 0 and counts["exit_other"] == 0
    finally:
        subprocess.call(["umount", mnt])


# ---------------------------------------------------------------------------------------
# two writers

def wait_for(predicate, timeout=120):
    end = time.time() + timeout
    while time.time() < end:
        if predicate():
            return True
        time.sleep(0.01)
    return False


def trial_writers(binary, work, _rng, n):
    results = {}
    kinds = {
        "run": lambda top, seed: [binary, "run", "--world", "home_store", "--frames-per-day",
                                  "150", "--quiet", "--seed", str(seed), "--out",
                                  os.path.join(top, "run"), "--map-out",
                                  os.path.join(top, "map.omnicml")],
        "simulate --overwrite": lambda top, seed: [binary, "simulate", "--world", "home_store",
                                                   "--frames-per-day", "40", "--seed", str(seed),
                                                   "--overwrite", "--out",
                                                   os.path.join(top, "log")],
    }
    ok_all = True
    for kind, argv in kinds.items():
        refused = first_ok = 0
        for trial in range(n):
            top = os.path.join(work, "writers_%s_%d" % (kind.split()[0], trial))
            os.makedirs(top)
            first = subprocess.Popen(argv(top, 1), stdout=subprocess.DEVNULL,
                                     stderr=subprocess.PIPE)
            lock = os.path.join(top, ".run.omnicml-lock" if kind == "run" else ".log.omnicml-lock")
            if not wait_for(lambda: os.path.exists(lock) or first.poll() is not None):
                print("  no lock seen")
            code, _, err = run(argv(top, 2))
            lines = [l for l in err.splitlines() if l.strip()]
            if (code == 2 and len(lines) == 1 and ("pid %d" % first.pid) in lines[0]
                    and "in use by another writer" in lines[0]):
                refused += 1
            else:
                print("  %s second writer: exit %d %r" % (kind, code, err[-300:]))
            first_err = first.communicate()[1].decode(errors="replace")
            if first.returncode == 0:
                first_ok += 1
            else:
                print("  %s first writer: exit %d %r" % (kind, first.returncode, first_err[-300:]))
        results[kind] = (refused, first_ok)
        ok_all = ok_all and refused == n and first_ok == n
    # Two sweeps into one directory.
    spec = os.path.join(work, "writers_spec.yaml")
    with open(spec, "w") as f:
        f.write("command: run\ninputs:\n  - {world: home_store, days: 1, frames_per_day: 150, "
                "name: hs}\nseeds: [1]\n")
    refused = first_ok = 0
    for trial in range(n):
        out = os.path.join(work, "writers_sweep_%d" % trial)
        first = subprocess.Popen([binary, "sweep", spec, "--out", out, "-j", "1"],
                                 stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        lock = os.path.join(work, ".writers_sweep_%d.omnicml-lock" % trial)
        wait_for(lambda: os.path.exists(lock) or first.poll() is not None)
        code, _, err = run([binary, "sweep", spec, "--out", out, "-j", "1"])
        if code == 2 and ("pid %d" % first.pid) in err:
            refused += 1
        else:
            print("  sweep second writer: exit %d %r" % (code, err[-300:]))
        first.communicate()
        first_ok += first.returncode == 0
    results["sweep"] = (refused, first_ok)
    ok_all = ok_all and refused == n and first_ok == n
    print("two writers at once: " + "; ".join(
        "%s: second refused %d/%d, first completed %d/%d" % (k, r, n, f, n)
        for k, (r, f) in results.items()))
    return ok_all


# ---------------------------------------------------------------------------------------
# sweep killed and rerun

def processes_in(directory):
    """Pids of processes whose command line mentions `directory`."""
    pids = []
    for pid in os.listdir("/proc"):
        if not pid.isdigit():
            continue
        try:
            cmd = open("/proc/%s/cmdline" % pid, "rb").read().decode(errors="replace")
        except OSError:
            continue
        if directory in cmd and int(pid) != os.getpid():
            pids.append(int(pid))
    return pids


def trial_sweep(binary, work, rng, n):
    spec = os.path.join(work, "sweep_spec.yaml")
    with open(spec, "w") as f:
        f.write("command: run\ninputs:\n  - {world: home_store, days: 1, frames_per_day: 60, "
                "name: hs}\nseeds: [1, 2]\noptions:\n  forgetting: [passive, active]\n")
    out_ref = os.path.join(work, "sweep_ref")
    t0 = time.time()
    code, _, err = run([binary, "sweep", spec, "--out", out_ref, "-j", "2"])
    assert code == 0, err
    duration = time.time() - t0
    modes = ["SIGKILL to the process group", "SIGTERM", "SIGINT"]
    completed = 0
    orphans = 0
    per_mode = {m: [0, 0] for m in modes}
    for trial in range(n):
        out = os.path.join(work, "sweep_%02d" % trial)
        mode = modes[trial % len(modes)]
        p = subprocess.Popen([binary, "sweep", spec, "--out", out, "-j", "2"],
                             stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                             start_new_session=True)
        time.sleep(rng.uniform(0.2, 0.9) * duration)
        if mode == modes[0]:
            os.killpg(p.pid, signal.SIGKILL)
        else:
            p.send_signal(signal.SIGTERM if mode == "SIGTERM" else signal.SIGINT)
        p.wait()
        # Nothing of it runs on (jobs die with Snakemake, Snakemake with omnicml sweep).
        if not wait_for(lambda: not processes_in(out), timeout=60):
            orphans += 1
            print("  processes outlived the sweep:", processes_in(out))
        code, stdout, err = run([binary, "sweep", spec, "--out", out, "-j", "2"])
        per_mode[mode][1] += 1
        if code == 0 and "4 run(s) collected" in stdout:
            completed += 1
            per_mode[mode][0] += 1
        else:
            print("  rerun after %s: exit %d %r" % (mode, code, (stdout + err)[-400:]))
    print("sweep killed and rerun: %d trials (kill at U(0.2, 0.9) x %.1f s): %d reruns completed "
          "with all 4 jobs collected (%s); processes outliving the killed sweep: %d"
          % (n, duration, completed,
             ", ".join("%s %d/%d" % (m, a, b) for m, (a, b) in per_mode.items()), orphans))
    return completed == n and orphans == 0


def main():
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--binary", default=os.path.join(ROOT, "build", "omnicml"))
    parser.add_argument("--trials", type=int, default=30)
    parser.add_argument("--seed", type=int, default=1)
    parser.add_argument("--only", nargs="*",
                        default=["substitutions", "follow", "kill", "window", "diskfull",
                                 "writers", "sweep"])
    args = parser.parse_args()
    binary = os.path.abspath(args.binary)
    rng = random.Random(args.seed)
    ok = True
    trials = {"substitutions": (trial_substitutions, 1), "follow": (trial_follow, 1),
              "kill": (trial_kill, args.trials), "window": (trial_window, args.trials),
              "diskfull": (trial_diskfull, args.trials), "writers": (trial_writers, 10),
              "sweep": (trial_sweep, 20)}
    for name in args.only:
        work = tempfile.mkdtemp(prefix="omnicml-trials-%s-" % name)
        try:
            fn, n = trials[name]
            ok = fn(binary, work, rng, n) and ok
        finally:
            subprocess.call(["umount", os.path.join(work, "tmpfs")], stderr=subprocess.DEVNULL)
            shutil.rmtree(work, ignore_errors=True)
        sys.stdout.flush()
    return 0 if ok else 1


if __name__ == "__main__":
    sys.exit(main())

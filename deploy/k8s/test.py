#!/usr/bin/env python3
"""Tests deploy/k8s without Kubernetes.

Kubernetes cannot run here, so this test reads the manifests, checks their shape (an Indexed
Job whose `completions` is ARBOR_PIECES, its podFailurePolicy against the render's exit codes,
the shared volume mounted at one path everywhere, the binary where the Dockerfile puts it), and
then runs each pod's command as the kubelet would: the container's environment built from the
ConfigMap and `env` (with JOB_COMPLETION_INDEX for each index), `$(NAME)` expanded in the
command, the volume's mount path mapped to a temporary folder and the image's binary to
$ARBOR_RENDER. It interrupts one pod with SIGTERM mid-render and runs its replacement, runs the
merge Job's command, and compares the merged EXR with a single render byte for byte; then the
same split by sample ranges; then a pod with a broken scene, whose exit code must fail the Job.

The manifests run as written, with one setting changed as `kubectl edit configmap` would:
ARBOR_SPP=8 (the scene's 64 would only take longer).

    python3 deploy/k8s/test.py        (ARBOR_RENDER: default target/debug/render)
"""

import math
import os
import re
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

try:
    import yaml
except ImportError:
    # As the GPU tests do: a missing prerequisite skips, except under CI=true.
    ci = os.environ.get("CI") == "true"
    print(f"k8s test: {'FAIL' if ci else 'SKIP'}: needs PyYAML (apt-get install python3-yaml)")
    sys.exit(1 if ci else 0)

HERE = Path(__file__).resolve().parent
ROOT = HERE.parent.parent
TEST_SETTINGS = {"ARBOR_SPP": "8"}
START = time.monotonic()


def say(message):
    print(f"k8s test [{time.monotonic() - START:.0f}s]: {message}", flush=True)


class Failure(Exception):
    pass


def check(condition, message):
    if not condition:
        raise Failure(message)


def load(name):
    with open(HERE / name) as f:
        return yaml.safe_load(f)


def expand(text, env):
    """Kubernetes' expansion of a command or an env value: `$(NAME)` becomes NAME's value where
    NAME is defined (else it stays), `$$` becomes `$`, and any other `$` stays."""
    out, i = [], 0
    while i < len(text):
        if text[i] != "$" or i + 1 == len(text):
            out.append(text[i])
            i += 1
        elif text[i + 1] == "$":
            out.append("$")
            i += 2
        elif text[i + 1] == "(" and (end := text.find(")", i + 2)) != -1:
            name = text[i + 2 : end]
            out.append(env.get(name, text[i : end + 1]))
            i = end + 1
        else:
            out.append(text[i : i + 2])
            i += 2
    return "".join(out)


def cpu_cores(quantity):
    """A CPU quantity ("2", "1500m") in cores, rounded up as the downward API rounds it."""
    quantity = str(quantity)
    if quantity.endswith("m"):
        return math.ceil(int(quantity[:-1]) / 1000)
    return math.ceil(float(quantity))


def failure_action(job, container, exit_code):
    """What the Job's podFailurePolicy does with a pod whose container exited with exit_code:
    the first rule that matches, else Count (towards backoffLimit)."""
    for rule in job["spec"].get("podFailurePolicy", {}).get("rules", []):
        codes = rule.get("onExitCodes")
        if not codes or codes.get("containerName", container) != container:
            continue
        listed = exit_code in codes["values"]
        if listed == (codes["operator"] == "In"):
            return rule["action"]
    return "Count"


class Manifests:
    """The manifests, checked for the shape the test and a cluster rely on."""

    def __init__(self):
        self.settings = load("settings.yaml")
        self.pvc = load("pvc.yaml")
        self.render = load("render-job.yaml")
        self.merge = load("merge-job.yaml")
        self.data_pod = load("data-pod.yaml")
        dockerfile = (HERE / "Dockerfile").read_text()
        copies = re.findall(r"^COPY --from=\S+ \S+ (\S+)$", dockerfile, re.M)
        check(len(copies) == 1, "the Dockerfile should copy one binary from its build stage")
        self.binary = copies[0]

        check(self.settings["kind"] == "ConfigMap", "settings.yaml is not a ConfigMap")
        check("ReadWriteMany" in self.pvc["spec"]["accessModes"],
              "the volume must be ReadWriteMany: pods on many nodes write to it")
        self.mount = None
        for job in (self.render, self.merge):
            self.check_pod(job["metadata"]["name"], job["spec"]["template"]["spec"])
            check(job["apiVersion"] == "batch/v1" and job["kind"] == "Job",
                  f"{job['metadata']['name']} is not a batch/v1 Job")
            check(job["spec"]["template"]["spec"]["restartPolicy"] == "Never",
                  f"{job['metadata']['name']}: podFailurePolicy needs restartPolicy Never")
        self.check_pod("data-pod", self.data_pod["spec"])

        spec = self.render["spec"]
        check(spec.get("completionMode") == "Indexed", "render-job.yaml is not an Indexed Job")
        self.completions = spec["completions"]
        check(isinstance(self.completions, int) and self.completions >= 1,
              "render-job.yaml: completions must be a positive number")
        check(1 <= spec.get("parallelism", 1) <= self.completions,
              "render-job.yaml: parallelism must be from 1 to completions")
        check(str(self.completions) == self.settings["data"]["ARBOR_PIECES"],
              f"completions ({self.completions}) and ARBOR_PIECES "
              f"({self.settings['data']['ARBOR_PIECES']}) differ: pieces would be missing")
        check(spec.get("backoffLimit", 6) >= 1, "render-job.yaml: no retries")
        check(self.render["spec"]["template"]["spec"].get("terminationGracePeriodSeconds", 30)
              >= 60, "render-job.yaml: too little time to write the state after SIGTERM")
        render = self.render_container()
        expected = {2: "FailJob", 3: "FailJob", 75: "Ignore", 69: "Count", 74: "Count", 1: "Count"}
        for code, action in expected.items():
            got = failure_action(self.render, render["name"], code)
            check(got == action, f"render-job.yaml: exit {code} should be {action}, is {got}")
        check(any(c.get("type") == "DisruptionTarget"
                  for r in spec["podFailurePolicy"]["rules"] if r["action"] == "Ignore"
                  for c in r.get("onPodConditions", [])),
              "render-job.yaml: an evicted or pre-empted pod should not count as a failure")
        check("JOB_COMPLETION_INDEX" in " ".join(self.command(render)),
              "render-job.yaml: the command does not read JOB_COMPLETION_INDEX")
        check(failure_action(self.merge, self.merge_container()["name"], 2) == "FailJob",
              "merge-job.yaml: exit 2 should fail the Job")
        check(self.merge["spec"].get("completionMode", "NonIndexed") == "NonIndexed"
              and self.merge["spec"].get("completions", 1) == 1,
              "merge-job.yaml should run one pod")
        for key in ("ARBOR_SCENE", "ARBOR_OUT"):
            check(self.settings["data"][key].startswith(self.mount + "/"),
                  f"{key} is not on the volume ({self.mount})")

    def check_pod(self, what, pod):
        """One container, the ConfigMap's settings, the claim mounted at the one path."""
        check(len(pod["containers"]) == 1, f"{what}: one container expected")
        container = pod["containers"][0]
        volumes = {v["name"]: v for v in pod["volumes"]}
        mounts = container.get("volumeMounts", [])
        check(len(mounts) == 1, f"{what}: one volume mount expected")
        volume = volumes[mounts[0]["name"]]
        check(volume.get("persistentVolumeClaim", {}).get("claimName")
              == self.pvc["metadata"]["name"], f"{what}: does not mount the claim of pvc.yaml")
        if self.mount is None:
            self.mount = mounts[0]["mountPath"]
        check(mounts[0]["mountPath"] == self.mount,
              f"{what}: mounts the volume at {mounts[0]['mountPath']}, not {self.mount}")
        if what != "data-pod":
            check({"configMapRef": {"name": self.settings["metadata"]["name"]}}
                  in container.get("envFrom", []), f"{what}: does not read settings.yaml")
            check(self.binary in " ".join(self.command(container)),
                  f"{what}: does not run {self.binary}, where the Dockerfile puts the binary")

    def render_container(self):
        return self.render["spec"]["template"]["spec"]["containers"][0]

    def merge_container(self):
        return self.merge["spec"]["template"]["spec"]["containers"][0]

    @staticmethod
    def command(container):
        return container.get("command", []) + container.get("args", [])


class Cluster:
    """Runs pods' commands on this machine: the volume is a folder, the image the host."""

    def __init__(self, manifests, render, data):
        self.m = manifests
        self.render = render
        self.data = data

    def local(self, text):
        return text.replace(self.m.binary, self.render).replace(
            self.m.mount + "/", f"{self.data}/")

    def pod(self, container, settings, index=None):
        """The command line and environment of a pod of this container."""
        env = {"PATH": os.environ.get("PATH", "/usr/bin:/bin")}
        for source in container.get("envFrom", []):
            check(source["configMapRef"]["name"] == self.m.settings["metadata"]["name"],
                  "unknown ConfigMap")
            env.update(settings)
        for var in container.get("env", []):
            if "value" in var:
                env[var["name"]] = expand(var["value"], env)
                continue
            ref = var.get("valueFrom", {}).get("resourceFieldRef")
            check(ref and ref["resource"] == "limits.cpu",
                  f"env {var['name']}: the test knows values and limits.cpu only")
            env[var["name"]] = str(cpu_cores(container["resources"]["limits"]["cpu"]))
        if index is not None:
            env["JOB_COMPLETION_INDEX"] = str(index)
        env = {k: self.local(v) for k, v in env.items()}
        argv = [self.local(expand(a, env)) for a in self.m.command(container)]
        return argv, env

    def start(self, container, settings, index=None):
        argv, env = self.pod(container, settings, index)
        return subprocess.Popen(argv, env=env, cwd=self.data, stdout=subprocess.PIPE,
                                stderr=subprocess.STDOUT, text=True)

    def run(self, container, settings, index=None):
        process = self.start(container, settings, index)
        output, _ = process.communicate(timeout=300)
        return process.returncode, output


def catches_term(pid, render):
    """Whether process pid is the render (not yet the shell before its exec) and has its
    SIGTERM handler (bit 14 of SigCgt)."""
    try:
        comm = Path(f"/proc/{pid}/comm").read_text().strip()
        with open(f"/proc/{pid}/status") as f:
            mask = next(line.split()[1] for line in f if line.startswith("SigCgt:"))
    except (OSError, StopIteration):
        return False
    return comm == Path(render).name[:15] and (int(mask, 16) >> 14) & 1 == 1


def render_pieces(cluster, settings, interrupt=None):
    """The Indexed Job: every index once, two at a time, as pods would; pod `interrupt` gets
    SIGTERM first, and its replacement must resume it. Returns whether that pod wrote a state
    (a signal while the scene loads writes none), `None` without `interrupt`."""
    m = cluster.m
    container = m.render_container()
    state_written = None
    if interrupt is not None:
        # The render must be mid-render, with its SIGTERM handler, when the signal comes,
        # however fast the binary and the machine: it runs in slices of a few milliseconds
        # until it has the handler, and is held while the signal is sent. The kubelet sends
        # SIGTERM to the container's process, which the command's exec makes the render.
        process = cluster.start(container, settings, interrupt)
        os.kill(process.pid, signal.SIGSTOP)
        deadline = time.monotonic() + 60
        while not catches_term(process.pid, cluster.render):
            check(process.poll() is None, f"pod {interrupt} ended before it caught SIGTERM")
            check(time.monotonic() < deadline, f"pod {interrupt} never caught SIGTERM")
            os.kill(process.pid, signal.SIGCONT)
            time.sleep(0.002)
            os.kill(process.pid, signal.SIGSTOP)
        os.kill(process.pid, signal.SIGTERM)
        os.kill(process.pid, signal.SIGCONT)
        output, _ = process.communicate(timeout=300)
        action = failure_action(m.render, container["name"], process.returncode)
        check(process.returncode == 75,
              f"pod {interrupt} exited {process.returncode} after SIGTERM, not 75:\n{output}")
        check(action == "Ignore", f"exit 75 should be ignored by podFailurePolicy, is {action}")
        say(f"pod {interrupt}: SIGTERM, exit 75 ({action}: the Job starts a replacement)")
        # A signal while the scene still loads ends the pod with nothing written: the
        # replacement then starts afresh instead of resuming.
        state_written = "while loading the scene" not in output
    running = []
    for index in range(m.completions):
        running.append((index, cluster.start(container, settings, index)))
        while len(running) >= 2 or (running and index == m.completions - 1):
            i, process = running.pop(0)
            output, _ = process.communicate(timeout=300)
            check(process.returncode == 0, f"pod {i} exited {process.returncode}:\n{output}")
    return state_written


def main():
    render = os.path.realpath(os.environ.get("ARBOR_RENDER", ROOT / "target/debug/render"))
    check(os.access(render, os.X_OK), f"no render binary at {render} (build it, or set ARBOR_RENDER)")
    m = Manifests()
    say(f"manifests: an Indexed Job of {m.completions} pods, its failure policy, volume "
        f"{m.pvc['metadata']['name']} at {m.mount} in every pod, {m.binary} as in the Dockerfile")

    with tempfile.TemporaryDirectory(prefix="arbor-k8s-test.") as tmp:
        data = Path(tmp) / "volume"
        shutil.copytree(ROOT / "scenes", data / "scenes")
        cluster = Cluster(m, render, data)
        settings = dict(m.settings["data"], **TEST_SETTINGS)
        flags = settings["ARBOR_FLAGS"].split()
        scene = cluster.local(settings["ARBOR_SCENE"])

        say(f"reference: one render of {settings['ARBOR_SCENE']} at {settings['ARBOR_SPP']} spp")
        reference = Path(tmp) / "single.exr"
        subprocess.run([render, scene, "-o", reference, "--spp", settings["ARBOR_SPP"],
                        "--quiet", *flags], check=True)
        other_seed = Path(tmp) / "seed1.exr"
        subprocess.run([render, scene, "-o", other_seed, "--spp", settings["ARBOR_SPP"],
                        "--seed", "1", "--quiet", *flags], check=True)

        for split, interrupt in (("tile", 0), ("samples", None)):
            run = dict(settings, ARBOR_SPLIT=split,
                       ARBOR_OUT=f"{settings['ARBOR_OUT']}-{split}")
            say(f"ARBOR_SPLIT={split}: {m.completions} pods")
            state_written = render_pieces(cluster, run, interrupt)
            out = Path(cluster.local(run["ARBOR_OUT"]))
            if interrupt is not None:
                report = (out / "reports" / f"piece-{interrupt:04d}-of-{m.completions:04d}.json")
                status = "resumed" if state_written else "rendered"
                check(f'"status": "{status}"' in report.read_text(),
                      f"pod {interrupt}'s replacement was not {status}:\n{report.read_text()}")
                say(f"pod {interrupt}'s replacement {status}" +
                    (" from the state" if state_written else " afresh (the signal came while loading)"))
            code, output = cluster.run(m.merge_container(), run)
            check(code == 0, f"the merge exited {code}:\n{output}")
            image = (out / run["ARBOR_IMAGE"]).read_bytes()
            check(image == reference.read_bytes(),
                  f"{split}: the merged image differs from the single render")
            check(image != other_seed.read_bytes(),
                  "the comparison cannot fail: a render with seed 1 is the same")
            say(f"{split}: merged == single render, byte for byte ({len(image)} bytes)")

        bad = data / "scenes" / "broken.toml"
        bad.write_text("this is not a scene\n")
        run = dict(settings, ARBOR_SCENE=f"{m.mount}/scenes/broken.toml",
                   ARBOR_OUT=f"{settings['ARBOR_OUT']}-broken")
        code, _ = cluster.run(m.render_container(), run, 0)
        action = failure_action(m.render, m.render_container()["name"], code)
        check(code == 2 and action == "FailJob",
              f"a pod with a broken scene exited {code} ({action}), not 2 (FailJob)")
        say("a broken scene: exit 2, which fails the Job without retries")
    say("passed")


if __name__ == "__main__":
    try:
        main()
    except (Failure, subprocess.CalledProcessError, OSError, KeyError, yaml.YAMLError) as e:
        say(f"FAIL: {e}")
        sys.exit(1)

"""Sending an exported scene to a tilefarm farm: `coordinator submit --wait`, run as a
child process (the farm's gRPC client is the coordinator executable; the add-on needs
no Python gRPC). The farm's address and token come from the add-on's preferences and
travel in the environment, never on a command line another user could read."""

import os
import re
import subprocess

# `submit --wait` prints the job's id first, then (its standard error not being a
# terminal) a line "progress: 42% · …" whenever the percent changes, at most one a second;
# the last percent seen is shown.
_PERCENT = re.compile(r"(\d+(?:\.\d+)?)\s*%")
_JOB = re.compile(r"^job-\d+$")


class Submission:
    """One `coordinator submit --wait` running in the background."""

    def __init__(self, coordinator, url, token, scene_toml, output, name):
        env = dict(os.environ)
        env["TILEFARM_COORDINATOR"] = url
        if token:
            env["TILEFARM_TOKEN"] = token
        else:
            env.pop("TILEFARM_TOKEN", None)
        self.output = output
        self.percent = 0.0
        self.lines = []
        self.job = None
        self._coordinator, self._env = coordinator, env
        self.proc = subprocess.Popen(
            [coordinator, "submit", scene_toml, "--wait", "--name", name, "-o", output],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
        )
        os.set_blocking(self.proc.stdout.fileno(), False)

    def _heard(self, line):
        self.lines.append(line)
        if self.job is None and _JOB.match(line):
            self.job = line
        found = _PERCENT.findall(line)
        if found:
            self.percent = float(found[-1])

    def poll(self):
        """Reads what the child printed; None while it runs, else its exit code."""
        while True:
            try:
                chunk = self.proc.stdout.read()
            except (BlockingIOError, TypeError):
                chunk = None
            if not chunk:
                break
            for line in re.split(r"[\r\n]+", chunk):
                if line.strip():
                    self._heard(line.strip())
            self.lines = self.lines[-50:]
        return self.proc.poll()

    def status_text(self, elapsed):
        """What Blender's status bar shows while the job runs."""
        return f"tilefarm: {self.percent:.0f}% after {elapsed:.0f} s (Esc cancels)"

    def wait(self):
        """Blocks until the child ends (headless use); its exit code."""
        os.set_blocking(self.proc.stdout.fileno(), True)
        out, _ = self.proc.communicate()
        for line in re.split(r"[\r\n]+", out or ""):
            if line.strip():
                self._heard(line.strip())
        return self.proc.returncode

    def error(self):
        """The child's last words, for a failed submission."""
        return "\n".join(self.lines[-5:]) or "coordinator submit failed"

    def cancel(self):
        """Cancels the job on the farm (what it rendered so far is kept there), then stops
        following it. Before the farm named the job, only the following stops."""
        self.poll()
        if self.job is not None and self.proc.poll() is None:
            subprocess.run([self._coordinator, "cancel", self.job], env=self._env, capture_output=True, timeout=30)
            try:
                # It sees the cancel and ends, writing what was rendered so far.
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                pass
        if self.proc.poll() is None:
            self.proc.terminate()
            self.proc.wait(timeout=30)

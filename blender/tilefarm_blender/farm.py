"""Sending an exported scene to a tilefarm farm: `coordinator submit --wait`, run as a
child process (the farm's gRPC client is the coordinator executable; the add-on needs
no Python gRPC). The farm's address and token come from the add-on's preferences and
travel in the environment, never on a command line another user could read."""

import os
import re
import subprocess

# `submit --wait` prints progress as "… 42% …" (or "42.0%"); the last one seen is shown.
_PERCENT = re.compile(r"(\d+(?:\.\d+)?)\s*%")


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
        self.proc = subprocess.Popen(
            [coordinator, "submit", scene_toml, "--wait", "--name", name, "-o", output],
            env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, bufsize=1,
        )
        os.set_blocking(self.proc.stdout.fileno(), False)

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
                    self.lines.append(line.strip())
                    found = _PERCENT.findall(line)
                    if found:
                        self.percent = float(found[-1])
            self.lines = self.lines[-50:]
        return self.proc.poll()

    def wait(self):
        """Blocks until the child ends (headless use); its exit code."""
        os.set_blocking(self.proc.stdout.fileno(), True)
        out, _ = self.proc.communicate()
        if out:
            self.lines += [ln.strip() for ln in re.split(r"[\r\n]+", out) if ln.strip()]
        return self.proc.returncode

    def error(self):
        """The child's last words, for a failed submission."""
        return "\n".join(self.lines[-5:]) or "coordinator submit failed"

    def cancel(self):
        if self.proc.poll() is None:
            self.proc.terminate()

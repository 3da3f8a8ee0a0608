"""Deadline 10 plugin: runs `gsid denoise` over a task's frames (a chunk of a frame pattern).

Install: copy this folder to <repository>/custom/plugins/GsidDenoise and set the gsid binary's
absolute path in Configure Plugins (GsidDenoise.param). Submit with farm/deadline/job_info.job and
plugin_info.job. gsid prints progress lines on stderr when it has no terminal; PROGRESS_REGEX
takes the whole task's percent from them (farm/README.md documents the line).
"""

import os

from Deadline.Plugins import DeadlinePlugin, PluginType
from Deadline.Scripting import FileUtils, RepositoryUtils  # noqa: F401 (RepositoryUtils for site hooks)

# `gsid: frame 1003: 40 % (frame 3 of 8, run 29 %, stage gsid, ETA 0:00:12)`: group 1 is the run's
# (the task's) percent. tests/it/farm.rs checks this line against gsid's real output.
PROGRESS_REGEX = r"^gsid: .*\brun (\d+) %, stage (\S+)"
ERROR_REGEX = r"^gsid: error: (.*)"


def GetDeadlinePlugin():
    return GsidDenoisePlugin()


def CleanupDeadlinePlugin(deadlinePlugin):
    deadlinePlugin.Cleanup()


class GsidDenoisePlugin(DeadlinePlugin):
    def __init__(self):
        super().__init__()
        self.InitializeProcessCallback += self.InitializeProcess
        self.RenderExecutableCallback += self.RenderExecutable
        self.RenderArgumentCallback += self.RenderArgument

    def Cleanup(self):
        for handler in self.StdoutHandlers:
            del handler.HandleCallback
        del self.InitializeProcessCallback
        del self.RenderExecutableCallback
        del self.RenderArgumentCallback

    def InitializeProcess(self):
        self.PluginType = PluginType.Simple
        self.SingleFramesOnly = False
        self.StdoutHandling = True
        self.PopupHandling = False
        self.AddStdoutHandlerCallback(PROGRESS_REGEX).HandleCallback += self.HandleProgress
        self.AddStdoutHandlerCallback(ERROR_REGEX).HandleCallback += self.HandleError
        threads = self.Threads()
        # gsid takes --threads; RAYON_NUM_THREADS bounds any pool it does not size itself.
        self.SetEnvironmentAndLogInfo("RAYON_NUM_THREADS", str(threads))

    def Threads(self):
        """The plugin info's Threads, else the Worker's CPU affinity, else the CPUs this process may use."""
        threads = self.GetIntegerPluginInfoEntryWithDefault("Threads", 0)
        if threads <= 0 and self.OverrideCpuAffinity():
            threads = len(self.CpuAffinity())
        if threads <= 0:
            threads = len(os.sched_getaffinity(0))
        return max(1, threads)

    def RenderExecutable(self):
        exe = FileUtils.SearchFileList(self.GetConfigEntry("GsidExecutable"))
        if not exe:
            self.FailRender("no gsid binary found at the paths of GsidExecutable (Configure Plugins)")
        return exe

    def RenderArgument(self):
        entry = self.GetPluginInfoEntry
        for key in ("InputPattern", "OutputPattern"):
            if not os.path.isabs(entry(key)):
                self.FailRender("%s must be an absolute path, got %s" % (key, entry(key)))
        args = [
            "denoise",
            '"%s"' % entry("InputPattern"),
            "-o",
            '"%s"' % entry("OutputPattern"),
            "--frames",
            "%d-%d" % (self.GetStartFrame(), self.GetEndFrame()),
            "--skip-existing",
            "--pipeline",
            '"%s"' % self.GetPluginInfoEntryWithDefault("Pipeline", "full"),
            "--temporal",
            str(self.GetIntegerPluginInfoEntryWithDefault("Temporal", 0)),
            "--threads",
            str(self.Threads()),
        ]
        return " ".join(args)

    def HandleProgress(self):
        self.SetProgress(float(self.GetRegexMatch(1)))
        self.SetStatusMessage("gsid: %s" % self.GetRegexMatch(2))

    def HandleError(self):
        self.LogWarning(self.GetRegexMatch(1))

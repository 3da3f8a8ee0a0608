#!/usr/bin/env python3
"""Submits a gsid denoise job to OpenCue with pyoutline: one Shell layer, one frame a task
(`#IFRAME#`, the frame RQD runs), the thread count from the cores the frame booked (CUE_THREADS).

    python3 denoise_shot.py --gsid /opt/gsid/bin/gsid \\
        --input /shots/sh010/render/beauty.####.exr \\
        --output /shots/sh010/denoised/beauty.####.exr --frames 1001-1100 --cores 4

Every path must be absolute. A requeued frame whose output exists is skipped (--skip-existing).
"""

import argparse
import os
import shlex
import sys


def command(args):
    """The shell command of one task: gsid on frame #IFRAME#, as many threads as the frame booked."""
    gsid = [
        args.gsid, "denoise", args.input, "-o", args.output,
        "--frames", "#IFRAME#", "--skip-existing",
        "--pipeline", args.pipeline, "--temporal", str(args.temporal),
    ]
    script = 'threads="${CUE_THREADS:-%d}"; export RAYON_NUM_THREADS="$threads"; exec %s --threads "$threads"' % (
        args.cores, " ".join(shlex.quote(a) for a in gsid))
    # RQD runs the layer's command as one string: the shell sees CUE_THREADS on the frame's host.
    return ["/bin/sh", "-c", shlex.quote(script)]


def main(argv=None):
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--gsid", required=True, help="absolute path of the gsid binary on the hosts")
    parser.add_argument("--input", required=True, help="absolute frame pattern of the noisy renders")
    parser.add_argument("--output", required=True, help="absolute frame pattern of the denoised frames")
    parser.add_argument("--frames", required=True, help="frame range, e.g. 1001-1100")
    parser.add_argument("--pipeline", default="full")
    parser.add_argument("--temporal", type=int, default=0, help="frames each side merged (0: alone)")
    parser.add_argument("--cores", type=int, default=4, help="cores a frame books (its CUE_THREADS)")
    parser.add_argument("--show", default=os.environ.get("SHOW", "testing"))
    parser.add_argument("--shot", default=os.environ.get("SHOT", "denoise"))
    parser.add_argument("--print", action="store_true", help="print the task command and exit")
    args = parser.parse_args(argv)
    for key in ("gsid", "input", "output"):
        if not os.path.isabs(getattr(args, key)):
            parser.error("--%s must be an absolute path" % key)
    if args.print:
        print(" ".join(command(args)))
        return 0

    from outline import Outline, cuerun
    from outline.modules.shell import Shell

    job = Outline("gsid_denoise_%s" % args.shot, shot=args.shot, show=args.show, user=os.environ.get("USER"))
    job.add_layer(Shell(
        "denoise", command=command(args), range=args.frames, chunk=1,
        cores=args.cores, overrideCores=True, threadable=True,
    ))
    cuerun.launch(job, use_pycuerun=False)
    return 0


if __name__ == "__main__":
    sys.exit(main())

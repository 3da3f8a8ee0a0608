// Flamenco 3 job type: denoise a frame range with gsid, a chunk of frames a task. Put this file in
// the Manager's `scripts/` folder (beside flamenco-manager) and restart it. Every path is absolute
// and the gsid binary is a setting, never a bare `gsid`. A Flamenco Worker runs one task at a
// time, so `threads` 0 lets gsid take every CPU the Worker's process may use.

const JOB_TYPE = {
    label: "gsid denoise",
    settings: [
        { key: "gsid", type: "string", subtype: "file_path", required: true,
          description: "Absolute path of the gsid binary on the Workers" },
        { key: "input", type: "string", subtype: "file_path", required: true,
          description: "Absolute frame pattern of the noisy renders, e.g. /shots/sh010/render/beauty.####.exr" },
        { key: "output", type: "string", subtype: "file_path", required: true,
          description: "Absolute frame pattern of the denoised frames, e.g. /shots/sh010/denoised/beauty.####.exr" },
        { key: "frames", type: "string", required: true,
          description: "Frames to denoise: '1001-1100', '1, 5, 9-12'" },
        { key: "chunk_size", type: "int32", default: 10, propargs: { min: 1 },
          description: "Frames one gsid process denoises" },
        { key: "pipeline", type: "string", default: "full",
          description: "A named pipeline (fast, balanced, quality, full) or the absolute path of a pipeline TOML" },
        { key: "temporal", type: "int32", default: 0, propargs: { min: 0, max: 8 },
          description: "Frames each side merged into a frame (0: each frame alone)" },
        { key: "threads", type: "int32", default: 0, propargs: { min: 0, max: 1024 },
          description: "Threads a task uses (0: every CPU of the Worker)" },
    ],
};

function compileJob(job) {
    const settings = job.settings;
    for (const key of ["gsid", "input", "output"]) {
        if (!settings[key].startsWith("/")) {
            throw `${key} must be an absolute path, got "${settings[key]}"`;
        }
    }
    for (const chunk of frameChunker(settings.frames, settings.chunk_size)) {
        const task = author.Task(`denoise-${chunk}`, "misc");
        const args = [
            "denoise", settings.input, "-o", settings.output,
            // frameChunker writes a chunk as `A-B` or `A,B,C`: both are gsid --frames lists.
            "--frames", chunk.replaceAll(" ", ""), "--skip-existing",
            "--pipeline", settings.pipeline, "--temporal", `${settings.temporal}`,
        ];
        if (settings.threads > 0) {
            args.push("--threads", `${settings.threads}`);
        }
        task.addCommand(author.Command("exec", { exe: settings.gsid, args: args }));
        job.addTask(task);
    }
}

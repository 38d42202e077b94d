//! The user's side of a farm: `submit` (upload, submit, optionally wait and fetch the
//! image), `status`, `update` (priority, pause, more samples) and `cancel`.

use std::path::PathBuf;

use anyhow::Context;
use clap::Args;

use crate::commands::follow::{Followed, JobFeed, follow};
use crate::commands::job_args::JobArgs;
use crate::commands::progress::{JobBar, summary};
use crate::edge::client::{FarmClient, StatusStream, Watch};
use crate::farm::assets::LocalScene;
use crate::farm::status::{JobState, JobStatus};

/// Where the farm is: shared by every command that talks to one.
#[derive(Args, Clone, Debug)]
pub struct FarmAddress {
    /// The coordinator: host:port or a URL, e.g. 10.0.0.5:7878 or http://10.0.0.5:7878
    /// (http:// is assumed when no scheme is given).
    #[arg(long = "coordinator", value_name = "ADDRESS", env = "TILEFARM_COORDINATOR")]
    pub address: String,
    /// Your access token on the farm (a `NAME.token` or `admin.token` file's contents
    /// from `coordinator certs init`, or `serve --token-file`'s).
    #[arg(long, value_name = "TOKEN", env = "TILEFARM_TOKEN", hide_env_values = true)]
    pub token: Option<String>,
    /// The farm's TLS folder, or a copy of its ca.pem's folder: connect over TLS,
    /// trusting only the farm's CA.
    #[arg(long, value_name = "DIR", env = "TILEFARM_TLS")]
    pub tls: Option<PathBuf>,
}

impl FarmAddress {
    pub async fn connect(&self) -> anyhow::Result<FarmClient> {
        let token = match &self.token {
            Some(t) => Some(proto::auth::Token::new(t).map_err(|e| anyhow::anyhow!("--token: {e}"))?),
            None => None,
        };
        let tls = self.tls.as_ref().map(proto::tls::TlsDir::new);
        FarmClient::connect(&self.address, token.as_ref(), tls.as_ref()).await
    }
}

#[derive(Args)]
pub struct SubmitArgs {
    /// Scene file (.toml) or a bare .obj; it and every file it refers to are uploaded.
    /// Several files, or one pattern with --frames, submit an animation: one job per
    /// frame, named NAME.0001, …, sharing the files that do not change.
    #[arg(required = true, num_args = 1.., value_name = "SCENE")]
    pub scenes: Vec<PathBuf>,
    /// Frames A to B of the scene pattern (its #### is the frame number, zero-padded):
    /// `submit 'shot/scene.####.toml' --frames 1-250`.
    #[arg(long, value_name = "A-B", value_parser = crate::commands::frames::frame_range)]
    pub frames: Option<(u32, u32)>,
    #[command(flatten)]
    pub coordinator: FarmAddress,
    /// The job's name in `status` [default: the scene file's name, or its folder's when
    /// the file is called scene.toml].
    #[arg(long, value_name = "NAME")]
    pub name: Option<String>,
    /// The job's weight in the farm's fair share of workers, 1 to 1000: of two running
    /// jobs, one of priority 150 gets three units for each one of priority 50.
    #[arg(long, value_name = "N", default_value_t = crate::farm::schedule::DEFAULT_PRIORITY,
          value_parser = clap::value_parser!(u32).range(1..=i64::from(crate::farm::schedule::MAX_PRIORITY)))]
    pub priority: u32,
    /// Wait for the job, showing progress, and write the image.
    #[arg(long)]
    pub wait: bool,
    /// With --wait: where the image goes.
    #[command(flatten)]
    pub image: ImageArgs,
    #[command(flatten)]
    pub job: JobArgs,
}

#[derive(Args)]
pub struct FetchArgs {
    /// The job id that `submit` printed (`status` lists them), or a job group's name:
    /// each of its frames in order, to the output with the frame number in place of its
    /// `####` (or before its extension).
    #[arg(value_name = "JOB|GROUP")]
    pub job: String,
    #[command(flatten)]
    pub coordinator: FarmAddress,
    #[command(flatten)]
    pub image: ImageArgs,
}

/// Where a followed job's image goes, and how its progress shows.
#[derive(Args)]
pub struct ImageArgs {
    /// The image file (.exr, or .png for a tone-mapped preview).
    #[arg(short, long, value_name = "FILE", default_value = "out.exr")]
    pub output: PathBuf,
    /// Rewrite a PNG preview of the image so far every few seconds.
    #[arg(long, value_name = "FILE.png")]
    pub preview: Option<PathBuf>,
    /// No progress bar.
    #[arg(long, short)]
    pub quiet: bool,
    /// Denoise the image on this machine with Intel Open Image Denoise (a build with
    /// `--features denoise`): an EXR keeps the farm's raw image and adds denoised.R/G/B;
    /// a PNG shows the denoised image. The job needs the AOV layers: `submit --denoise`
    /// asks for them (as --aovs does).
    #[arg(long)]
    pub denoise: bool,
}

impl ImageArgs {
    /// Refuses --denoise before anything is submitted or fetched where it cannot work.
    fn check(&self) -> anyhow::Result<()> {
        if self.denoise {
            tracer::denoise::check_available().map_err(|e| anyhow::anyhow!("--denoise: {e}"))?;
        }
        Ok(())
    }
}

#[derive(Args)]
pub struct StatusArgs {
    /// Only this job, or this job group's frames [default: every job].
    #[arg(value_name = "JOB|GROUP")]
    pub only: Option<String>,
    #[command(flatten)]
    pub coordinator: FarmAddress,
}

#[derive(Args)]
pub struct UpdateArgs {
    /// The job id that `submit` printed (`status` lists them), or a job group's name:
    /// every frame of it not yet finished.
    #[arg(value_name = "JOB|GROUP")]
    pub job: String,
    #[command(flatten)]
    pub coordinator: FarmAddress,
    /// A new priority, 1 to 1000 (its weight in the fair share of workers).
    #[arg(long, value_name = "N",
          value_parser = clap::value_parser!(u32).range(1..=i64::from(crate::farm::schedule::MAX_PRIORITY)))]
    pub priority: Option<u32>,
    /// Give the job no new units (those out finish and merge); its workers go to other jobs.
    #[arg(long, conflicts_with = "resume")]
    pub pause: bool,
    /// Give a paused job units again.
    #[arg(long)]
    pub resume: bool,
    /// Render more samples per pixel than the job was submitted with.
    #[arg(long, value_name = "N")]
    pub spp: Option<u32>,
}

#[derive(Args)]
pub struct CancelArgs {
    /// The job id that `submit` printed (`status` lists them), or a job group's name:
    /// every frame of it not yet finished.
    #[arg(value_name = "JOB|GROUP")]
    pub job: String,
    #[command(flatten)]
    pub coordinator: FarmAddress,
}

/// A job's default name: the scene file's stem (`cup.toml` → `cup`), or for the many
/// scenes called `scene.toml` the folder that holds them.
fn job_name(scene: &std::path::Path) -> String {
    let stem = scene.file_stem().map(|s| s.to_string_lossy().into_owned()).unwrap_or_default();
    if stem != "scene" {
        return stem;
    }
    let folder = std::path::absolute(scene).ok().and_then(|p| p.parent()?.file_name().map(|n| n.to_os_string()));
    folder.map_or(stem, |f| f.to_string_lossy().into_owned())
}

/// The job's options with the AOV layers that --denoise needs; refuses --denoise where
/// it cannot work, before anything is uploaded.
fn with_layers_for(mut job: JobArgs, image: &ImageArgs, wait: bool) -> anyhow::Result<JobArgs> {
    image.check()?;
    anyhow::ensure!(
        !image.denoise || wait,
        "--denoise denoises the image that --wait writes; without --wait, submit with --aovs and run \
         `coordinator fetch JOB --denoise` when it is done"
    );
    job.aovs |= image.denoise;
    Ok(job)
}

pub(crate) fn runtime() -> anyhow::Result<tokio::runtime::Runtime> {
    tokio::runtime::Builder::new_multi_thread().worker_threads(2).enable_all().build().context("async runtime")
}

pub fn submit(args: SubmitArgs) -> anyhow::Result<()> {
    if args.scenes.len() > 1 || args.frames.is_some() {
        return runtime()?.block_on(submit_frames(args));
    }
    let scene_path = args.scenes[0].clone();
    let args = SubmitArgs { job: with_layers_for(args.job, &args.image, args.wait)?, ..args };
    runtime()?.block_on(async move {
        if args.wait {
            tracer::output::check_output_paths(&args.image.output, args.image.preview.as_deref())?;
        }
        let local = LocalScene::collect(&scene_path)?;
        // Refused here, before a job exists: a job that cannot load only fails later.
        if !local.missing.is_empty() {
            let list: Vec<String> = local.missing.iter().map(|m| format!("  {}", local.relative(m))).collect();
            anyhow::bail!(
                "{} refers to files that are missing, so nothing was submitted:\n{}",
                scene_path.display(),
                list.join("\n")
            );
        }
        let mut client = args.coordinator.connect().await?;
        let scene = client.upload(&local.scene, local.relative(&local.scene)).await?;
        let mut assets = Vec::new();
        for f in &local.files {
            assets.push(client.upload(f, local.relative(f)).await?);
        }
        let name = args.name.clone().unwrap_or_else(|| job_name(&scene_path));
        let job = client.submit(name, args.priority, &args.job.spec_with_map(scene, assets)?).await?;
        println!("{job}");
        if args.wait {
            let stream = match client.watch(&job).await? {
                Watch::Stream(s) => s,
                Watch::NotFound(m) => anyhow::bail!("{m}"),
            };
            wait(&mut client, stream, &job, &args.image, &args.image.output, args.image.preview.as_deref()).await?;
        }
        Ok(())
    })
}

/// `submit` of an animation (see `commands::frames`): one job per frame, shared files
/// uploaded once; with --wait, each frame's image to the output pattern, in order.
async fn submit_frames(args: SubmitArgs) -> anyhow::Result<()> {
    use crate::commands::frames::{GroupUpload, frame_output, frame_scenes, group_name};
    let frames = frame_scenes(&args.scenes, args.frames)?;
    let args = SubmitArgs { job: with_layers_for(args.job, &args.image, args.wait)?, ..args };
    if args.wait {
        for (f, _) in &frames {
            tracer::output::check_output_paths(&frame_output(&args.image.output, *f), None)?;
        }
    }
    let group = args.name.clone().unwrap_or_else(|| group_name(&args.scenes[0]));
    let mut client = args.coordinator.connect().await?;
    let mut upload = GroupUpload::default();
    let mut jobs = Vec::with_capacity(frames.len());
    for (frame, scene) in &frames {
        let (scene_ref, assets) = upload.frame(&mut client, scene).await?;
        let mut spec = args.job.spec_with_map(scene_ref, assets)?;
        spec.group = Some(group.clone());
        let job = client.submit(format!("{group}.{frame:04}"), args.priority, &spec).await?;
        println!("{job}");
        jobs.push((*frame, job));
    }
    eprintln!(
        "submitted {} frame(s) as {group}.####: uploaded {} file(s), {} bytes ({} bytes as separate jobs)",
        jobs.len(),
        upload.files_sent,
        upload.sent,
        upload.per_frame
    );
    if args.wait {
        for (frame, job) in &jobs {
            let stream = match client.watch(job).await? {
                Watch::Stream(s) => s,
                Watch::NotFound(m) => anyhow::bail!("frame {frame}: {m}"),
            };
            let out = frame_output(&args.image.output, *frame);
            wait(&mut client, stream, job, &args.image, &out, None).await.with_context(|| format!("frame {frame}"))?;
        }
    }
    Ok(())
}

async fn fetch_image(client: &mut FarmClient, job: &str) -> anyhow::Result<tracer::film::Image> {
    decode_exr(&client.fetch_exr(job).await?, job)
}

fn decode_exr(exr: &[u8], job: &str) -> anyhow::Result<tracer::film::Image> {
    let tmp = std::env::temp_dir().join(format!("tilefarm-fetch-{}-{job}.exr", std::process::id()));
    std::fs::write(&tmp, exr)?;
    let image = tracer::output::read_exr(&tmp);
    let _ = std::fs::remove_file(&tmp);
    Ok(image?)
}

/// Writes a fetched image: an EXR as the coordinator made it (header and all; with
/// `denoise`, a denoised layer added), a PNG tone-mapped from it. Returns the image.
async fn fetch_and_write(
    client: &mut FarmClient,
    job: &str,
    output: &std::path::Path,
    denoise: bool,
) -> anyhow::Result<tracer::film::Image> {
    let mut exr = client.fetch_exr(job).await?;
    let mut image = decode_exr(&exr, job)?;
    if denoise {
        anyhow::ensure!(
            !image.layers.is_empty(),
            "--denoise: job {job} was rendered without the AOV layers the denoiser needs (submit it with --aovs \
             or --denoise)"
        );
        let started = std::time::Instant::now();
        image.denoised = tracer::denoise::denoise(&image).map_err(|e| anyhow::anyhow!("--denoise: {e}"))?;
        exr = tracer::output::add_denoised_layer(&exr, &image.denoised)
            .map_err(|e| anyhow::anyhow!("--denoise: adding the denoised layer to job {job}'s EXR: {e}"))?;
        tracing::info!("denoised in {:.2} s", started.elapsed().as_secs_f64());
    }
    match tracer::output::Format::of(output)? {
        tracer::output::Format::Exr => {
            std::fs::write(output, &exr).with_context(|| format!("writing {}", output.display()))?
        }
        tracer::output::Format::Png => tracer::output::write_png(&image, output)?,
    }
    Ok(image)
}

/// `coordinator fetch`: follows a job to its end and writes its image.
pub fn fetch(args: FetchArgs) -> anyhow::Result<()> {
    args.image.check()?;
    tracer::output::check_output_paths(&args.image.output, args.image.preview.as_deref())?;
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let Some(frames) = group_members(&mut client, &args.job).await? else {
            let preview = args.image.preview.as_deref();
            return follow_and_write(&mut client, &args.job, &args.image, &args.image.output, preview).await;
        };
        // A group: each frame in order, to the output with its frame number.
        for (n, job) in frames.iter().map(|j| (frame_number(j), &j.job_id)) {
            let out = crate::commands::frames::frame_output(&args.image.output, n);
            tracer::output::check_output_paths(&out, None)?;
            follow_and_write(&mut client, job, &args.image, &out, None)
                .await
                .with_context(|| format!("frame {n} ({job})"))?;
        }
        Ok(())
    })
}

/// Follows `job` to its end and writes its image; a job that finished long ago (no
/// longer listed, its image stored) is written at once.
async fn follow_and_write(
    client: &mut FarmClient,
    job: &str,
    how: &ImageArgs,
    output: &std::path::Path,
    preview: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    let stream = match client.watch(job).await? {
        Watch::Stream(s) => s,
        Watch::NotFound(m) => {
            let image = match fetch_and_write(client, job, output, how.denoise).await {
                Ok(image) => image,
                Err(e) if e.to_string().starts_with("--denoise") => return Err(e),
                Err(_) => anyhow::bail!("{m}"),
            };
            if let Some(p) = preview {
                tracer::output::write_png(&image, p)?;
            }
            println!("{job} finished earlier; wrote {}", output.display());
            return Ok(());
        }
    };
    wait(client, stream, job, how, output, preview).await
}

/// A frame's number: its job's name ends in it (`shot.0007`, as `submit` names frames).
fn frame_number(j: &JobStatus) -> u32 {
    j.scene.rsplit('.').next().and_then(|n| n.parse().ok()).unwrap_or(0)
}

/// A farm's job, followed over gRPC.
struct RemoteJob<'a> {
    client: &'a mut FarmClient,
    job: &'a str,
    stream: StatusStream,
}

impl JobFeed for RemoteJob<'_> {
    async fn next_status(&mut self) -> anyhow::Result<Option<JobStatus>> {
        self.stream.next().await
    }

    async fn image(&mut self) -> anyhow::Result<tracer::film::Image> {
        fetch_image(self.client, self.job).await
    }
}

/// Follows `job` on its `watched` progress stream to its end and writes its image.
async fn wait(
    client: &mut FarmClient,
    stream: StatusStream,
    job: &str,
    how: &ImageArgs,
    output: &std::path::Path,
    preview: Option<&std::path::Path>,
) -> anyhow::Result<()> {
    let mut bar = JobBar::new(how.quiet);
    let followed = follow(&mut RemoteJob { client: &mut *client, job, stream }, &mut bar, preview).await;
    bar.finish();
    let status = match followed? {
        Followed::Ended(status) => *status,
        Followed::Interrupted => {
            anyhow::bail!("interrupted; the job goes on (cancel it with `coordinator cancel {job}`)")
        }
    };
    match status.state {
        JobState::Done => {
            let image = fetch_and_write(client, job, output, how.denoise).await?;
            if let Some(p) = preview {
                tracer::output::write_png(&image, p)?;
            }
            println!("{}; wrote {}", summary(&status, 0, 0), output.display());
            Ok(())
        }
        JobState::Failed => anyhow::bail!("job {job} failed: {}", status.error),
        JobState::Cancelled if status.width > 0 => {
            // What was rendered before the cancel is still worth having.
            fetch_and_write(client, job, output, how.denoise).await?;
            anyhow::bail!(
                "job {job} was cancelled; wrote the image so far ({:.1}% of its samples; the samples channel \
                 shows each pixel's) to {}",
                100.0 * status.samples_done as f64 / status.samples_total.max(1) as f64,
                output.display()
            )
        }
        JobState::Cancelled => anyhow::bail!("job {job} was cancelled before its scene loaded"),
        s => anyhow::bail!("job {job} stopped in state {s:?}"),
    }
}

pub fn status(args: StatusArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let mut jobs = client.jobs().await?;
        let workers = client.workers().await?;
        if let Some(only) = &args.only {
            // A group's frames as `fetch NAME` finds them: listed, or stored (finished
            // before a restart, or no longer listed).
            match group_members(&mut client, only).await? {
                Some(members) => jobs = members,
                None => jobs.retain(|j| &j.job_id == only),
            }
            // A job no longer listed (finished before a restart, or forgotten after
            // `retain`) whose image `fetch` would still write.
            if jobs.is_empty() {
                jobs.extend(client.stored_job(only).await?);
            }
            anyhow::ensure!(!jobs.is_empty(), "no job or job group {only} on the farm");
        }
        // Written at once, and a reader that stops early (`status | head`) is no error.
        use std::fmt::Write as _;
        let mut out = String::new();
        let mut groups: Vec<&str> = Vec::new();
        for j in jobs.iter().filter(|j| !j.group.is_empty()) {
            if !groups.contains(&j.group.as_str()) {
                groups.push(&j.group);
            }
        }
        if !groups.is_empty() {
            writeln!(out, "groups:")?;
        }
        for g in groups {
            let frames: Vec<&JobStatus> = jobs.iter().filter(|j| j.group == g).collect();
            writeln!(out, "  {}", crate::commands::progress::group_line(g, &frames))?;
        }
        writeln!(out, "jobs:")?;
        if jobs.is_empty() {
            writeln!(out, "  (none)")?;
        }
        for j in jobs {
            writeln!(out, "  {}", crate::commands::progress::status_line(&j))?;
            for w in &j.warnings {
                writeln!(out, "      ! {w}")?;
            }
        }
        writeln!(out, "workers:")?;
        for w in workers {
            writeln!(
                out,
                "  {:<4} {:<20} {:>3} threads  {:>3} held  {:>6} done  seen {:.1}s ago{}",
                w.id,
                w.hostname,
                w.threads,
                w.units_held,
                w.units_done,
                w.last_seen_s,
                if w.quarantined { "  QUARANTINED (its identity is banned: coordinator workers)" } else { "" }
            )?;
        }
        print_all(&out)
    })
}

/// Writes `text` to standard output; a reader that has gone (a closed pipe) ends it
/// quietly.
fn print_all(text: &str) -> anyhow::Result<()> {
    use std::io::Write;
    let mut stdout = std::io::stdout().lock();
    match stdout.write_all(text.as_bytes()).and_then(|()| stdout.flush()) {
        Err(e) if e.kind() != std::io::ErrorKind::BrokenPipe => {
            Err(anyhow::Error::from(e).context("writing the status"))
        }
        _ => Ok(()),
    }
}

pub fn update(args: UpdateArgs) -> anyhow::Result<()> {
    let paused = if args.pause {
        Some(true)
    } else if args.resume {
        Some(false)
    } else {
        None
    };
    let change = crate::farm::state::JobChange { priority: args.priority, paused, spp: args.spp };
    if change == crate::farm::state::JobChange::default() {
        anyhow::bail!("nothing to change: give --priority, --pause, --resume or --spp");
    }
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let Some(frames) = group_frames(&mut client, &args.job, "update").await? else {
            let s = client.update(&args.job, &change).await?;
            println!("{}", crate::commands::progress::status_line(&s));
            return Ok(());
        };
        anyhow::ensure!(
            change.spp.is_none(),
            "--spp on a job group: raise its frames' spp one by one, once they run (queued frames have not loaded)"
        );
        for f in frames {
            let s = client.update(&f, &change).await?;
            println!("{}", crate::commands::progress::status_line(&s));
        }
        Ok(())
    })
}

/// The frames of the job group `name`, listed or with their images stored, in frame
/// order; None when `name` is a listed job's id, or no job group has that name.
async fn group_members(client: &mut FarmClient, name: &str) -> anyhow::Result<Option<Vec<JobStatus>>> {
    let jobs = client.jobs().await?;
    if jobs.iter().any(|j| j.job_id == name) {
        return Ok(None);
    }
    let mut members: Vec<JobStatus> = jobs.into_iter().filter(|j| j.group == name).collect();
    // Frames that finished before a restart, or were forgotten after `retain`, are no
    // longer listed; their images are still stored.
    if is_group_name(name) {
        for stored in client.stored_frames(name).await? {
            if !members.iter().any(|m| m.job_id == stored.job_id) {
                members.push(stored);
            }
        }
    }
    if members.is_empty() {
        return Ok(None);
    }
    members.sort_by_key(frame_number);
    Ok(Some(members))
}

/// Whether `name` could be a job group's (the farm refuses to look up others).
fn is_group_name(name: &str) -> bool {
    proto::wire::group_from_proto(name.to_string()).is_ok_and(|g| g.is_some())
}

/// The unfinished frames of the job group `name`, last first (so that cancelling them
/// never lets a queued frame start on the way); None as for [`group_members`]. When
/// every frame has ended there are none, and the user is told so with the group's line,
/// rather than `what` (the command) printing nothing at all.
async fn group_frames(client: &mut FarmClient, name: &str, what: &str) -> anyhow::Result<Option<Vec<String>>> {
    let Some(members) = group_members(client, name).await? else { return Ok(None) };
    let open: Vec<String> = members.iter().rev().filter(|j| !j.state.is_final()).map(|j| j.job_id.clone()).collect();
    if open.is_empty() {
        let all: Vec<&JobStatus> = members.iter().collect();
        println!("{}: every frame has ended, nothing to {what}", crate::commands::progress::group_line(name, &all));
    }
    Ok(Some(open))
}

pub fn cancel(args: CancelArgs) -> anyhow::Result<()> {
    runtime()?.block_on(async move {
        let mut client = args.coordinator.connect().await?;
        let jobs = match group_frames(&mut client, &args.job, "cancel").await? {
            Some(frames) => frames,
            None => vec![args.job.clone()],
        };
        for job in jobs {
            let s = client.cancel(&job).await?;
            println!("{} {}", s.job_id, s.state.name());
        }
        Ok(())
    })
}

#[cfg(test)]
mod tests {
    use std::path::Path;

    use super::job_name;

    #[test]
    fn jobs_are_named_by_their_scene_or_its_folder() {
        assert_eq!(job_name(Path::new("scenes/cornell-box/scene.toml")), "cornell-box");
        assert_eq!(job_name(Path::new("shots/hero.toml")), "hero");
        assert_eq!(job_name(Path::new("model.obj")), "model");
    }
}

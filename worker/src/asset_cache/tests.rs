//! Tests of the asset cache: digests, job folders, loading (also prepared), the
//! in-memory scene cache.

use super::*;

/// What `prepare_job` does once the files are fetched: the prepared scene, else the files.
fn load_job(cache: &AssetCache, job: &JobSpec) -> anyhow::Result<LoadedJob> {
    match read_prepared(cache, job) {
        Some(loaded) => Ok(loaded),
        None => load_from_files(cache, job),
    }
}

fn temp_root(name: &str) -> PathBuf {
    let dir = std::env::temp_dir().join(format!("tilefarm-worker-test-{name}-{}", temp_suffix()));
    let _ = fs::remove_dir_all(&dir);
    dir
}

fn asset_of(path: &str, content: &[u8]) -> AssetRef {
    AssetRef { path: path.into(), sha256: hex::encode(Sha256::digest(content)), size: content.len() as u64 }
}

#[test]
fn asset_paths_are_sanitised() {
    assert_eq!(sanitize_asset_path("scene.toml").unwrap(), PathBuf::from("scene.toml"));
    assert_eq!(sanitize_asset_path("./meshes/./a.obj").unwrap(), PathBuf::from("meshes/a.obj"));
    assert_eq!(sanitize_asset_path("tex/wood grain.png").unwrap(), PathBuf::from("tex/wood grain.png"));
    for bad in ["", ".", "/etc/passwd", "../x.obj", "a/../../x", "a/..", "meshes\\a.obj", "C:/x.obj", "a\0b"] {
        let e = sanitize_asset_path(bad).unwrap_err().to_string();
        assert!(e.contains("refused"), "{bad:?}: {e}");
    }
    assert!(sanitize_asset_path("../x").unwrap_err().to_string().contains(".."));
    assert!(sanitize_asset_path("/x").unwrap_err().to_string().contains("absolute"));
    assert!(sanitize_asset_path("a\\b").unwrap_err().to_string().contains("backslash"));
}

#[test]
fn job_ids_and_digests_are_checked() {
    assert!(check_job_id("0123abcd-ef").is_ok());
    for bad in ["", "..", ".hidden", "a/b", "a\\b", &"x".repeat(129)] {
        assert!(check_job_id(bad).is_err(), "{bad}");
    }
    assert!(check_digest(&"0f".repeat(32)).is_ok());
    assert!(check_digest(&"0F".repeat(32)).is_err());
    assert!(check_digest("../../etc/passwd").is_err());
    assert!(check_digest(&"0f".repeat(31)).is_err());
}

#[test]
fn a_verified_blob_is_published_and_a_corrupted_one_refused() {
    let root = temp_root("digest");
    let cache = AssetCache::open(&root).unwrap();
    let content = b"[camera]\nfov = 40\n".repeat(100);
    let good = asset_of("scene.toml", &content);

    // Same size, one byte flipped: the digest check refuses it and leaves nothing.
    let mut corrupted = content.clone();
    corrupted[17] ^= 1;
    let mut w = cache.blob_writer(&good).unwrap();
    w.write(&corrupted[..500]).unwrap();
    w.write(&corrupted[500..]).unwrap();
    let e = w.finish().unwrap_err().to_string();
    assert!(e.contains("digest") && e.contains("scene.toml"), "{e}");
    assert!(!cache.has_blob(&good));
    assert!(!cache.blob_path(&good.sha256).exists());

    // Truncated: refused.
    let mut w = cache.blob_writer(&good).unwrap();
    w.write(&content[..content.len() - 1]).unwrap();
    assert!(w.finish().unwrap_err().to_string().contains("expected"));
    assert!(!cache.has_blob(&good));

    // Too long: refused as soon as it overflows.
    let mut w = cache.blob_writer(&good).unwrap();
    w.write(&content).unwrap();
    assert!(w.write(b"x").is_err());
    drop(w);
    assert!(!cache.has_blob(&good));

    // Intact: published.
    let mut w = cache.blob_writer(&good).unwrap();
    for c in content.chunks(333) {
        w.write(c).unwrap();
    }
    let path = w.finish().unwrap();
    assert_eq!(fs::read(&path).unwrap(), content);
    assert!(cache.has_blob(&good));

    // No temp files are left behind.
    assert_eq!(fs::read_dir(root.join("tmp")).unwrap().count(), 0);
    let _ = fs::remove_dir_all(&root);
}

#[test]
fn jobs_are_laid_out_and_bad_paths_refused() {
    let root = temp_root("layout");
    let cache = AssetCache::open(&root).unwrap();
    let scene = asset_of("scene.toml", b"scene");
    let mesh = asset_of("meshes/box.obj", b"v 0 0 0\n");
    for a in [(&scene, &b"scene"[..]), (&mesh, &b"v 0 0 0\n"[..])] {
        let mut w = cache.blob_writer(a.0).unwrap();
        w.write(a.1).unwrap();
        w.finish().unwrap();
    }
    let job = JobSpec {
        job_id: "job1".into(),
        scene: scene.clone(),
        assets: vec![mesh.clone()],
        overrides: Default::default(),
        integrator: Integrator::Path,
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    };
    let scene_path = cache.lay_out_job(&job).unwrap();
    assert_eq!(scene_path, root.join("jobs/job1/scene.toml"));
    assert_eq!(fs::read(root.join("jobs/job1/meshes/box.obj")).unwrap(), b"v 0 0 0\n");
    // Laying out again is harmless.
    assert_eq!(cache.lay_out_job(&job).unwrap(), scene_path);

    let mut evil = job.clone();
    evil.assets[0].path = "../../outside.obj".into();
    let e = cache.lay_out_job(&evil).unwrap_err().to_string();
    assert!(e.contains("outside.obj") && e.contains(".."), "{e}");
    assert!(!root.join("outside.obj").exists());

    let mut clash = job.clone();
    clash.assets.push(AssetRef { path: "meshes/box.obj".into(), ..scene.clone() });
    assert!(cache.lay_out_job(&clash).unwrap_err().to_string().contains("twice"));

    let mut bad_id = job.clone();
    bad_id.job_id = "../x".into();
    assert!(cache.lay_out_job(&bad_id).is_err());
    let _ = fs::remove_dir_all(&root);
}

const TINY_SCENE: &str = "[camera]\nposition = [0, 0, -5]\nlook_at = [0, 0, 0]\nwidth = 64\nheight = 32\n\n\
    [[sphere]]\ncenter = [0, 0, 0]\nradius = 1\nkd = [0.5, 0.5, 0.5]\n";

fn put_blob(cache: &AssetCache, asset: &AssetRef, content: &[u8]) {
    let mut w = cache.blob_writer(asset).unwrap();
    w.write(content).unwrap();
    w.finish().unwrap();
}

#[test]
fn a_job_loads_with_its_overrides_and_a_broken_scene_names_its_file() {
    let root = temp_root("load");
    let cache = AssetCache::open(&root).unwrap();
    let scene = asset_of("sub/scene.toml", TINY_SCENE.as_bytes());
    put_blob(&cache, &scene, TINY_SCENE.as_bytes());
    let mut job = JobSpec {
        job_id: "j".into(),
        scene,
        assets: vec![],
        overrides: tracer::scene::Overrides { width: Some(32), spp: Some(3), ..Default::default() },
        integrator: Integrator::Normals,
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    };
    let loaded = load_job(&cache, &job).unwrap();
    assert_eq!((loaded.scene.camera.width, loaded.scene.camera.height), (32, 16));
    assert_eq!(loaded.scene.settings.spp, 3);
    assert_eq!(loaded.integrator, Integrator::Normals);

    let broken = b"[camera]\nposition = [0, 0".as_slice();
    job.scene = asset_of("broken.toml", broken);
    put_blob(&cache, &job.scene, broken);
    let e = format!("{:#}", load_job(&cache, &job).err().unwrap());
    assert!(e.contains("broken.toml"), "{e}");

    job.scene = asset_of("meshes/missing.obj", b"");
    assert!(load_job(&cache, &job).is_err(), "blob not cached");
    let _ = fs::remove_dir_all(&root);
}

/// The second load of a scene reads it prepared, and renders the same bits; a damaged
/// entry is loaded again from the files (and kept again).
#[test]
fn a_scene_loads_prepared_the_second_time_and_a_damaged_entry_is_rebuilt() {
    let root = temp_root("prepared");
    let scenes = PreparedScenes::open(&root.join("prepared"), 1 << 30).unwrap();
    let cache = AssetCache::open(&root).unwrap().with_prepared(scenes);
    let scene = asset_of("scene.toml", TINY_SCENE.as_bytes());
    put_blob(&cache, &scene, TINY_SCENE.as_bytes());
    let job = JobSpec {
        job_id: "j".into(),
        scene,
        assets: vec![],
        overrides: tracer::scene::Overrides { width: Some(16), ..Default::default() },
        integrator: Integrator::Path,
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    };
    let entry = || {
        let dir = root.join("prepared");
        fs::read_dir(&dir).unwrap().flatten().map(|e| e.path()).find(|p| p.extension().is_some_and(|x| x == "scene"))
    };
    // Kept in the background: wait for it (bounded).
    let kept = || {
        let t = Instant::now();
        while entry().is_none() {
            assert!(t.elapsed() < Duration::from_secs(20), "the prepared scene was never kept");
            std::thread::sleep(Duration::from_millis(10));
        }
        entry().unwrap()
    };
    let render = |l: &LoadedJob| {
        let tile = tracer::film::Tile::new(0, 0, 16, 8);
        tracer::render::render_unit(&l.scene, l.integrator, tile, tracer::film::SampleRange::new(0, 2))
    };
    let first = load_job(&cache, &job).unwrap();
    assert!(!first.prepared);
    let path = kept();
    // A prepared scene needs none of its files.
    fs::remove_file(cache.blob_path(&job.scene.sha256)).unwrap();
    let second = load_job(&cache, &job).unwrap();
    assert!(second.prepared, "the second load reads the prepared scene");
    assert_eq!(second.scene.camera.width, 16, "with the job's overrides");
    assert_eq!(render(&second), render(&first));

    let mut bytes = fs::read(&path).unwrap();
    let last = bytes.len() - 1;
    bytes[last] ^= 1;
    fs::write(&path, bytes).unwrap();
    assert!(load_job(&cache, &job).is_err(), "without the entry, the files are needed");
    put_blob(&cache, &job.scene, TINY_SCENE.as_bytes());
    let third = load_job(&cache, &job).unwrap();
    assert!(!third.prepared, "a damaged entry is not used");
    assert_eq!(render(&third), render(&first));
    kept();
    assert!(load_job(&cache, &job).unwrap().prepared, "and it is kept again");
    let _ = fs::remove_dir_all(&root);
}

#[test]
fn the_scene_cache_keeps_the_most_recent() {
    let spec = |id: &str| JobSpec {
        job_id: id.into(),
        scene: asset_of("scene.toml", TINY_SCENE.as_bytes()),
        assets: vec![],
        overrides: Default::default(),
        integrator: Integrator::Path,
        tile_size: None,
        batch_spp: None,
        spp_map: None,
        group: None,
    };
    let mk = |id: &str| {
        Arc::new(LoadedJob {
            spec: spec(id),
            scene: Arc::new(tracer::scene::scene_from_toml(TINY_SCENE, "test", Path::new(".")).unwrap()),
            integrator: Integrator::Path,
            prepared: false,
        })
    };
    let mut c = SceneCache::new(2);
    c.insert(mk("a"));
    c.insert(mk("b"));
    assert!(c.get(&spec("a")).is_some()); // a is now the most recent
    c.insert(mk("c"));
    assert!(c.get(&spec("b")).is_none());
    assert!(c.get(&spec("a")).is_some());
    assert!(c.get(&spec("c")).is_some());
    // Same id, other content (a restarted coordinator reusing ids): not the same job.
    let mut other = spec("c");
    other.scene = asset_of("scene.toml", b"another scene");
    assert!(c.get(&other).is_none());
    other = spec("c");
    other.overrides.spp = Some(7);
    assert!(c.get(&other).is_none());
}

//! `coordinator certs init DIR`: everything a farm needs to run over TLS with access
//! control, made with rcgen: a CA, the coordinator's certificate, worker certificates
//! (client authentication only) and access tokens, one per file.

use std::io::Write;
use std::path::{Path, PathBuf};

use anyhow::Context;
use clap::{Args, Subcommand};
use proto::auth::Token;
use proto::tls;
use rcgen::{
    BasicConstraints, CertificateParams, CertifiedIssuer, DnType, ExtendedKeyUsagePurpose, IsCa, Issuer, KeyPair,
    KeyUsagePurpose,
};

#[derive(Args)]
pub struct CertsArgs {
    #[command(subcommand)]
    pub command: CertsCommand,
}

#[derive(Subcommand)]
pub enum CertsCommand {
    /// Create a farm's TLS folder: ca.pem/ca.key (keep ca.key safe; nothing on the farm
    /// needs it), server.pem/server.key for `serve --tls DIR`, worker certificates for
    /// `worker --tls DIR`, admin.token and one NAME.token per user.
    Init(InitArgs),
}

#[derive(Args)]
pub struct InitArgs {
    /// The folder to create (it must not exist yet, or be empty).
    pub dir: PathBuf,
    /// Worker certificates to make: with 1, worker.pem/worker.key; with more,
    /// worker-1.pem … worker-N.pem (give each machine its own: `worker --tls DIR
    /// --tls-name worker-2`).
    #[arg(long, value_name = "N", default_value_t = 1, value_parser = clap::value_parser!(u32).range(1..=10_000))]
    pub workers: u32,
    /// Users to make tokens for (NAME.token); each sees and cancels only its own jobs.
    #[arg(long, value_name = "NAME", value_delimiter = ',', default_value = "user")]
    pub users: Vec<String>,
    /// Further names or addresses of the coordinator to put in its certificate (clients
    /// check the name `tilefarm-coordinator`, so this is only for other tools).
    #[arg(long, value_name = "NAME")]
    pub host: Vec<String>,
}

pub fn run(args: CertsArgs) -> anyhow::Result<()> {
    match args.command {
        CertsCommand::Init(a) => init(a),
    }
}

pub fn init(args: InitArgs) -> anyhow::Result<()> {
    for u in &args.users {
        anyhow::ensure!(
            !u.is_empty()
                && u != "admin"
                && u.len() <= 64
                && u.bytes().all(|b| b.is_ascii_alphanumeric() || b == b'-' || b == b'_'),
            "--users {u}: a user name is 1 to 64 letters, digits, - or _ (and not admin)"
        );
    }
    let dir = &args.dir;
    if dir.exists() {
        let empty = std::fs::read_dir(dir).with_context(|| format!("{}", dir.display()))?.next().is_none();
        anyhow::ensure!(empty, "{}: already exists and is not empty; certs init never overwrites keys", dir.display());
    }
    std::fs::create_dir_all(dir).with_context(|| format!("creating {}", dir.display()))?;
    restrict(dir, 0o700)?;

    let ca_key = KeyPair::generate()?;
    let mut ca = CertificateParams::new(Vec::<String>::new())?;
    ca.is_ca = IsCa::Ca(BasicConstraints::Constrained(0));
    ca.distinguished_name.push(DnType::CommonName, "tilefarm farm CA");
    ca.key_usages = vec![KeyUsagePurpose::KeyCertSign, KeyUsagePurpose::CrlSign];
    let ca = CertifiedIssuer::self_signed(ca, ca_key)?;
    write(dir, tls::CA_CERT, &ca.pem(), 0o644)?;
    write(dir, tls::CA_KEY, &ca.key().serialize_pem(), 0o600)?;

    let mut names = vec![tls::SERVER_NAME.to_string(), "localhost".into(), "127.0.0.1".into()];
    names.extend(args.host.iter().cloned());
    let (cert, key) = leaf(&ca, names, "tilefarm coordinator", ExtendedKeyUsagePurpose::ServerAuth)?;
    write(dir, tls::SERVER_CERT, &cert, 0o644)?;
    write(dir, tls::SERVER_KEY, &key, 0o600)?;

    let workers: Vec<String> = if args.workers == 1 {
        vec![tls::WORKER.to_string()]
    } else {
        (1..=args.workers).map(|i| format!("{}-{i}", tls::WORKER)).collect()
    };
    for w in &workers {
        let (cert, key) = leaf(&ca, vec![], &format!("tilefarm {w}"), ExtendedKeyUsagePurpose::ClientAuth)?;
        write(dir, &format!("{w}.pem"), &cert, 0o644)?;
        write(dir, &format!("{w}.key"), &key, 0o600)?;
    }
    let random = || Token::random().map_err(anyhow::Error::msg);
    write(dir, tls::ADMIN_TOKEN, &format!("{}\n", random()?.secret()), 0o600)?;
    for u in &args.users {
        write(dir, &format!("{u}.token"), &format!("{}\n", random()?.secret()), 0o600)?;
    }
    let d = dir.display();
    println!(
        "made {d}: a CA, the coordinator's certificate, {} worker certificate(s), admin.token and {} user token(s)",
        workers.len(),
        args.users.len()
    );
    println!("  coordinator:  coordinator serve --listen 0.0.0.0:7878 --tls {d}");
    println!(
        "  each worker:  worker --coordinator HOST:7878 --tls DIR   (DIR holding ca.pem and its {}.pem/.key)",
        workers[0]
    );
    println!(
        "  each user:    TILEFARM_TOKEN=$(cat {d}/{}.token) coordinator submit scene.toml --coordinator HOST:7878 --tls DIR",
        args.users.first().map_or("admin", |u| u.as_str())
    );
    println!("keep {d}/ca.key offline: no part of the farm needs it");
    Ok(())
}

/// A certificate for `names` signed by the farm's CA, usable only for `usage`.
fn leaf(
    ca: &Issuer<'_, KeyPair>,
    names: Vec<String>,
    common_name: &str,
    usage: ExtendedKeyUsagePurpose,
) -> anyhow::Result<(String, String)> {
    let key = KeyPair::generate()?;
    let mut p = CertificateParams::new(names)?;
    p.distinguished_name.push(DnType::CommonName, common_name);
    p.key_usages = vec![KeyUsagePurpose::DigitalSignature];
    p.extended_key_usages = vec![usage];
    let cert = p.signed_by(&key, ca)?;
    Ok((cert.pem(), key.serialize_pem()))
}

fn write(dir: &Path, name: &str, text: &str, mode: u32) -> anyhow::Result<()> {
    let path = dir.join(name);
    let mut options = std::fs::OpenOptions::new();
    options.write(true).create_new(true);
    #[cfg(unix)]
    std::os::unix::fs::OpenOptionsExt::mode(&mut options, mode);
    let mut f = options.open(&path).with_context(|| format!("creating {}", path.display()))?;
    f.write_all(text.as_bytes()).with_context(|| format!("writing {}", path.display()))?;
    Ok(())
}

fn restrict(dir: &Path, mode: u32) -> anyhow::Result<()> {
    #[cfg(unix)]
    {
        use std::os::unix::fs::PermissionsExt;
        std::fs::set_permissions(dir, std::fs::Permissions::from_mode(mode))
            .with_context(|| format!("{}", dir.display()))?;
    }
    Ok(())
}

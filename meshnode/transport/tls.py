"""Optional TLS on every link (the standard `ssl` module): who may hold a certificate is the
cluster operator's business; this module turns three file options into the two contexts a
peer needs, one to listen and one to dial.

TLS adds confidentiality and certificate-checked identity to the cluster secret's
challenge-response (protocols.handshake), which runs inside the TLS channel unchanged. A node
listening with a certificate and key takes only TLS connections; with a CA it also demands
a client certificate signed by that CA (mutual TLS) and checks its neighbours' certificates
against it when it dials them. Hostnames are always checked: certificates must name the
addresses peers dial (DNS names, or IP addresses as IP subject alternative names).

`ssl` is imported when a context is made: the options alone (a render's command line) need
none of it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import ssl

MIN_VERSION = "TLSv1_2"  # the oldest `ssl.TLSVersion` a link accepts


@dataclass(frozen=True)
class TlsFiles:
    """Paths of a PEM certificate chain, its private key and the CA bundle that signs the
    cluster's certificates (None: not given)."""

    cert: str | None = None
    key: str | None = None
    ca: str | None = None

    def __post_init__(self):
        if (self.cert is None) != (self.key is None):
            raise ValueError("--tls-cert and --tls-key go together (a certificate and its key)")

    @property
    def enabled(self) -> bool:
        return self.cert is not None or self.ca is not None

    def server(self) -> ssl.SSLContext | None:
        """The listening side's context: None without a certificate (plain TCP)."""
        if self.cert is None:
            return None
        import ssl

        ctx = ssl.SSLContext(ssl.PROTOCOL_TLS_SERVER)
        ctx.minimum_version = ssl.TLSVersion[MIN_VERSION]
        _load(ctx, self)
        if self.ca is not None:
            ctx.verify_mode = ssl.CERT_REQUIRED
        return ctx

    def client(self) -> ssl.SSLContext | None:
        """The dialling side's context: None when TLS is off; checks the peer's certificate
        (against the CA, or the system's) and its hostname, and offers our certificate."""
        if not self.enabled:
            return None
        import ssl

        ctx = ssl.create_default_context(ssl.Purpose.SERVER_AUTH)
        ctx.minimum_version = ssl.TLSVersion[MIN_VERSION]
        _load(ctx, self)
        return ctx


def _load(ctx: ssl.SSLContext, files: TlsFiles) -> None:
    """Certificate, key and CA into `ctx`, failing with the file that could not be used."""
    import ssl

    try:
        if files.cert is not None:
            ctx.load_cert_chain(files.cert, files.key)
        if files.ca is not None:
            ctx.load_verify_locations(cafile=files.ca)
    except (OSError, ssl.SSLError) as e:
        which = f"--tls-cert {files.cert} / --tls-key {files.key}, --tls-ca {files.ca}"
        raise ValueError(f"cannot use the TLS files ({which}): {e.strerror or e}") from e


NO_TLS = TlsFiles()  # plain TCP


def add_tls_options(parser, whose: str) -> None:
    """--tls-cert, --tls-key, --tls-ca: the same three options on `meshnode serve` and
    `host render`."""
    parser.add_argument("--tls-cert", help=f"TLS: {whose} certificate chain (PEM)")
    parser.add_argument("--tls-key", help="TLS: the certificate's private key (PEM)")
    parser.add_argument(
        "--tls-ca",
        help="TLS: the CA bundle that signs the cluster's "
        "certificates; peers must present one it signs",
    )

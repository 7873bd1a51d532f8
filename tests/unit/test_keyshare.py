from zdrone.core.keys import Identity
from zdrone.core.keyshare import open_secret, seal_secret

A, X = Identity(bytes([5]) * 32), Identity(bytes([6]) * 32)
SECRET = bytes(range(32))


def test_only_the_asker_opens_the_shared_secret():
    sealed = seal_secret(SECRET, A.public, "d1", "B", "A")
    assert len(sealed) == 80 and SECRET not in sealed
    assert open_secret(sealed, A, "d1", "B", "A") == SECRET
    assert open_secret(sealed, X, "d1", "B", "A") is None
    assert open_secret(sealed, A, "d2", "B", "A") is None  # bound to the drone
    assert open_secret(sealed[:-1] + bytes([sealed[-1] ^ 1]), A, "d1", "B", "A") is None
    assert open_secret(b"junk", A, "d1", "B", "A") is None

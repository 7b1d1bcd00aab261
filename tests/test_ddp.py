"""DDP: two CPU processes on the gloo backend train the tiny preset on two scenes; each rank
draws its own samples, yet all parameters (translator, discriminators and the replicated
textures of both scenes) stay identical across ranks. A SIGTERM that only rank 1 receives
stops both ranks at the same step, with a checkpoint of that step."""

import datetime
import os
import signal

import torch
import torch.multiprocessing as mp
from train_data import real_dir, scene_dir, tiny_config

from sim2real.engine.checkpoint import load_checkpoint

ITERS = 3  # steps trained: rank 1 gets a SIGTERM during the last one (of ITERS + 3 configured)


def _worker(rank, world, init_file, scenes, real, out, results):
    import torch.distributed as dist

    from sim2real.engine.trainer import Trainer

    torch.set_num_threads(1)
    # a rank left waiting in a collective (the ranks disagreeing on the stop) fails instead of hanging
    dist.init_process_group("gloo", init_method=f"file://{init_file}", rank=rank, world_size=world,
                            timeout=datetime.timedelta(seconds=120))
    try:
        cfg = tiny_config(iterations=ITERS + 3, image_every=100, device="cpu")
        trainer = Trainer(cfg, scenes, real, out, progress=False)
        assert trainer.dist.world_size == world and trainer.dist.rank == rank
        losses = {}
        trainer.hooks.append(lambda s, v: losses.__setitem__(s, v))
        if rank == 1:  # a real signal, to this rank's process only
            trainer.hooks.append(lambda s, v: os.kill(os.getpid(), signal.SIGTERM) if s == ITERS - 1 else None)
        trainer.train()
        assert trainer.stopped_by == signal.SIGTERM and trainer.step == ITERS
        sampled = [int(trainer.dataset[s]["scene"]) for s in range(ITERS)]
        torch.save({"gen": trainer.gen.state_dict(), "dis": trainer.dis.state_dict(), "losses": losses,
                    "sampled": sampled}, f"{results}/rank{rank}.pt")
    finally:
        dist.destroy_process_group()


def test_two_process_gloo_ddp_keeps_ranks_identical(tmp_path, tmp_path_factory):
    base = tmp_path_factory.getbasetemp()
    scenes = [str(scene_dir(base, 11)), str(scene_dir(base, 12))]
    real = str(real_dir(base))
    out = tmp_path / "run"
    mp.spawn(_worker, args=(2, str(tmp_path / "store"), scenes, real, str(out), str(tmp_path)), nprocs=2, join=True)
    r0, r1 = (torch.load(tmp_path / f"rank{r}.pt", weights_only=True) for r in (0, 1))
    # the ranks trained on different samples ...
    assert r0["losses"][0]["gen/rec_a"] != r1["losses"][0]["gen/rec_a"]
    # ... but gradients were averaged, so every parameter is the same on both
    for part in ("gen", "dis"):
        assert r0[part].keys() == r1[part].keys()
        for k in r0[part]:
            assert torch.equal(r0[part][k], r1[part][k]), f"{part}.{k} differs between ranks"
    # and training moved them, the textures of every scene a rank sampled included
    start = load_checkpoint(out / "checkpoints" / "step_0000000.pt")
    keys = [s["key"] for s in start["scenes"]]
    for idx in set(r0["sampled"]) | set(r1["sampled"]):
        k = f"textures.{keys[idx]}.texture"
        assert not torch.equal(start["gen"][k], r0["gen"][k]), k
    assert not torch.equal(start["gen"]["translator.enc_a.model.0.conv.weight"], r0["gen"]["translator.enc_a.model.0.conv.weight"])
    end = load_checkpoint(out / "checkpoints" / "last.pt")
    assert sorted(r0["losses"]) == sorted(r1["losses"]) == list(range(ITERS))  # both stopped after step ITERS
    assert end["step"] == ITERS and end["world_size"] == 2 and len(end["rng"]) == 2
    assert all(torch.equal(end["gen"][k], r0["gen"][k]) for k in r0["gen"])

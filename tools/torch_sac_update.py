"""Time one SAC update in PyTorch on this machine, for `mbpo bench sac-update`'s comparison.

The update is the one MBPO's SAC does (softlearning / CleanRL layout): twin Q critics with
Polyak-averaged targets, tanh-squashed Gaussian actor with log-std clamp, automatic entropy
temperature, Adam for all three, one gradient step each per update. Dimensions default to the
issue's (HalfCheetah: obs 17, act 6, two hidden layers of 256, batch 256).

    bash tools/torch_sac_update.sh --threads 1
    -> {"framework": "pytorch", "torch": "...", "threads": 1, "ms_per_update": ...}

Prints the median over rounds of the mean time per update within a round (after warm-up),
as one JSON line, like the Rust benchmark.
"""

import argparse
import json
import statistics
import time

import torch
from torch import nn


def mlp(inp, out, hidden):
    layers, last = [], inp
    for h in hidden:
        layers += [nn.Linear(last, h), nn.ReLU()]
        last = h
    layers.append(nn.Linear(last, out))
    return nn.Sequential(*layers)


class Actor(nn.Module):
    def __init__(self, obs, act, hidden):
        super().__init__()
        self.net = mlp(obs, 2 * act, hidden)
        self.act = act

    def sample(self, s):
        mu, log_std = self.net(s).split(self.act, dim=-1)
        log_std = log_std.clamp(-20.0, 2.0)
        std = log_std.exp()
        u = mu + std * torch.randn_like(mu)
        a = torch.tanh(u)
        log_prob = (-0.5 * ((u - mu) / std) ** 2 - log_std - 0.9189385332046727).sum(-1)
        log_prob = log_prob - (2.0 * (0.6931471805599453 - u - nn.functional.softplus(-2.0 * u))).sum(-1)
        return a, log_prob


def main():
    p = argparse.ArgumentParser()
    p.add_argument("--threads", type=int, default=1)
    p.add_argument("--obs", type=int, default=17)
    p.add_argument("--act", type=int, default=6)
    p.add_argument("--hidden", type=int, default=256)
    p.add_argument("--batch", type=int, default=256)
    p.add_argument("--rounds", type=int, default=15)
    p.add_argument("--per-round", type=int, default=20)
    args = p.parse_args()
    torch.set_num_threads(args.threads)
    torch.manual_seed(0)
    o, a, b, hid = args.obs, args.act, args.batch, [args.hidden, args.hidden]

    actor = Actor(o, a, hid)
    q1, q2 = mlp(o + a, 1, hid), mlp(o + a, 1, hid)
    q1_t, q2_t = mlp(o + a, 1, hid), mlp(o + a, 1, hid)
    q1_t.load_state_dict(q1.state_dict())
    q2_t.load_state_dict(q2.state_dict())
    for p_ in list(q1_t.parameters()) + list(q2_t.parameters()):
        p_.requires_grad_(False)
    log_alpha = torch.zeros(1, requires_grad=True)
    target_entropy = -float(a)
    gamma, tau = 0.99, 0.005
    q_opt = torch.optim.Adam(list(q1.parameters()) + list(q2.parameters()), lr=3e-4)
    pi_opt = torch.optim.Adam(actor.parameters(), lr=3e-4)
    a_opt = torch.optim.Adam([log_alpha], lr=3e-4)
    q_params = list(q1.parameters()) + list(q2.parameters())
    qt_params = list(q1_t.parameters()) + list(q2_t.parameters())

    s, s2 = torch.randn(b, o), torch.randn(b, o)
    act = torch.tanh(torch.randn(b, a))
    r, term = torch.randn(b), torch.zeros(b)

    def update():
        alpha = log_alpha.exp().detach()
        with torch.no_grad():
            a2, logp2 = actor.sample(s2)
            x2 = torch.cat([s2, a2], -1)
            q_next = torch.min(q1_t(x2), q2_t(x2)).squeeze(-1) - alpha * logp2
            y = r + gamma * (1.0 - term) * q_next
        x = torch.cat([s, act], -1)
        q_loss = ((q1(x).squeeze(-1) - y) ** 2).mean() + ((q2(x).squeeze(-1) - y) ** 2).mean()
        q_opt.zero_grad(set_to_none=True)
        q_loss.backward()
        q_opt.step()

        a_new, logp = actor.sample(s)
        xn = torch.cat([s, a_new], -1)
        pi_loss = (alpha * logp - torch.min(q1(xn), q2(xn)).squeeze(-1)).mean()
        pi_opt.zero_grad(set_to_none=True)
        pi_loss.backward()
        pi_opt.step()

        alpha_loss = -(log_alpha * (logp.detach() + target_entropy)).mean()
        a_opt.zero_grad(set_to_none=True)
        alpha_loss.backward()
        a_opt.step()

        with torch.no_grad():
            torch._foreach_lerp_(qt_params, q_params, tau)

    for _ in range(10):
        update()
    per_round = []
    for _ in range(args.rounds):
        t0 = time.perf_counter()
        for _ in range(args.per_round):
            update()
        per_round.append((time.perf_counter() - t0) / args.per_round * 1e3)
    print(
        json.dumps(
            {
                "framework": "pytorch",
                "torch": torch.__version__,
                "threads": args.threads,
                "obs": o,
                "act": a,
                "hidden": args.hidden,
                "batch": b,
                "ms_per_update": round(statistics.median(per_round), 3),
                "ms_per_update_best": round(min(per_round), 3),
            }
        )
    )


if __name__ == "__main__":
    main()

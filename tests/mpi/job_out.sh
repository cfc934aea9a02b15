# Sourced by the multi-rank test scripts that run a job and read what it
# wrote: job_out NAME ARGS... sets $out to the job's --out DIR (exit 2 naming
# the script when there is none) and empties it, so a run reads only its own.
job_out() {
  local name="$1" i
  shift
  local -a args=("$@")
  out=""
  for ((i = 0; i < ${#args[@]}; ++i)); do
    [[ "${args[i]}" == --out ]] && out="${args[i + 1]}"
  done
  [[ -n "$out" ]] || { echo "$name: the job needs --out DIR" >&2; exit 2; }
  rm -rf "$out"
}

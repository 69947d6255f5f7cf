# shellcheck shell=bash
# Sourced by the launch scripts (not run): `quote` prints its arguments as one line a shell takes back.
quote() {  # the arguments as one line a shell takes back: plain words bare, others in '...'
  local arg line=""
  for arg in "$@"; do
    if [[ $arg =~ ^[][A-Za-z0-9_./:=@%+,-]+$ ]]; then line+="$arg "; else line+="${arg@Q} "; fi
  done
  echo "${line% }"
}
